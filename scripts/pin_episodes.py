"""Pin the episodes of the benchmark version: the digests ``rsb verify`` and tests/audit/test_golden.py check.

Writes ``rsb_maniskill/audit/golden_episodes.json`` (on the real GSM8K / MMLU-Pro: ``--data-dir`` or
``$RSB_DATA_DIR``) and ``tests/fixtures/golden_fixture.json`` (on the tests' small fixture data,
what the tests use without ``$RSB_DATA_DIR``). A change to any suite's episodes is a new benchmark
version, so the digests of a version are written once:

    python scripts/pin_episodes.py                                  # check: which suites drifted (exit 1)
    python scripts/pin_episodes.py --bump 1.2 --note "General: ..."  # a new version: version.py, docs, digests
    python scripts/pin_episodes.py --amend --note "..."              # re-pin the current, unreleased version
    python scripts/pin_episodes.py --write                          # first pin, re-write unchanged digests, or
                                                                    # pin a new kind of digest (additive amendment)

``--bump`` sets ``BENCHMARK_VERSION`` in rsb_maniskill/version.py, adds the version's section to
docs/versions.md (the note and the suites whose episodes changed) and writes both digest files.
``--amend`` is for a version not yet released (merged, not tagged): it re-pins the current version,
adds the note to its section and lists again the suites that changed since the previous version
(each digest file keeps the previous version's digests under ``previous``). ``--write`` also pins
a digest of a new kind of episode that the file does not hold yet (the ``counterfactual`` variants
were added to RSB-MS 1.1 so): no pinned digest may change, so no episode of the version does.
See docs/versions.md.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rsb_maniskill.audit import golden  # noqa: E402
from rsb_maniskill.version import BENCHMARK, BENCHMARK_VERSION  # noqa: E402

FIXTURE_DATA = ROOT / "tests" / "fixtures" / "semantic_data"
FIXTURE_GOLDEN = ROOT / "tests" / "fixtures" / "golden_fixture.json"
VERSION_FILE = ROOT / "rsb_maniskill" / "version.py"
VERSIONS_DOC = ROOT / "docs" / "versions.md"
VERSIONS_ANCHOR = "## Versions\n"


def parse_version(text: str) -> tuple[int, ...]:
    if not re.fullmatch(r"\d+\.\d+", text):
        raise SystemExit(f"pin_episodes: a benchmark version is MAJOR.MINOR (1.2), got {text!r}")
    return tuple(int(p) for p in text.split("."))


def changed_suites(diff: dict[str, list[str]]) -> str:
    return "; ".join(f"{eid} ({', '.join(which)})" for eid, which in diff.items()) or "none"


def set_version(new: str) -> None:
    text = VERSION_FILE.read_text()
    VERSION_FILE.write_text(re.sub(r'^BENCHMARK_VERSION = "[^"]+"$', f'BENCHMARK_VERSION = "{new}"', text, count=1,
                                   flags=re.M))


CHANGED = "- Episodes changed (pinned digests): "


def add_doc_section(version: str, note: str, diff: dict[str, list[str]]) -> None:
    doc = VERSIONS_DOC.read_text()
    if VERSIONS_ANCHOR not in doc:
        raise SystemExit(f"pin_episodes: {VERSIONS_DOC} has no '{VERSIONS_ANCHOR.strip()}' heading")
    section = f"{VERSIONS_ANCHOR}\n### {BENCHMARK} {version}\n\n- {note}\n{CHANGED}{changed_suites(diff)}.\n"
    VERSIONS_DOC.write_text(doc.replace(VERSIONS_ANCHOR, section, 1))


def amend_doc_section(version: str, note: str, diff: dict[str, list[str]]) -> None:
    """The note first in the version's section; its list of changed suites, from the previous version."""
    doc = VERSIONS_DOC.read_text()
    head = f"### {BENCHMARK} {version}\n\n"
    if head not in doc:
        raise SystemExit(f"pin_episodes: {VERSIONS_DOC} has no section '{head.strip()}' to amend")
    start = doc.index(head)
    end = doc.find("\n### ", start + len(head))
    end = end if end >= 0 else len(doc)
    section = re.sub(f"^{re.escape(CHANGED)}.*$", lambda _: f"{CHANGED}{changed_suites(diff)}.", doc[start:end],
                     flags=re.M)
    VERSIONS_DOC.write_text(doc[:start] + section.replace(head, f"{head}- {note}\n", 1) + doc[end:])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--bump", metavar="MAJOR.MINOR", help="pin the episodes as this new benchmark version")
    mode.add_argument("--amend", action="store_true", help="re-pin the current version (not released yet)")
    mode.add_argument("--write", action="store_true", help="pin the current version where it is not pinned yet")
    p.add_argument("--note", default=None, help="what changed, for docs/versions.md (with --bump / --amend)")
    p.add_argument("--data-dir", default=None, help="the real GSM8K / MMLU-Pro (default $RSB_DATA_DIR)")
    args = p.parse_args()
    data = args.data_dir or os.environ.get("RSB_DATA_DIR")
    if not data or Path(data).resolve() == FIXTURE_DATA.resolve():
        raise SystemExit("pin_episodes: the pinned digests are of the real GSM8K / MMLU-Pro: give --data-dir or "
                         "$RSB_DATA_DIR (a directory with gsm8k/ and mmlu_pro/, see docs/semantic.md)")
    if (args.bump or args.amend) and not args.note:
        raise SystemExit("pin_episodes: --bump and --amend need --note 'what changed' for docs/versions.md")

    t0 = time.perf_counter()
    digests = {golden.GOLDEN_FILE: golden.compute(data_dir=data), FIXTURE_GOLDEN: golden.compute(data_dir=FIXTURE_DATA)}
    kinds = len(next(iter(digests[FIXTURE_GOLDEN].values())))
    print(f"pin_episodes: {len(digests[FIXTURE_GOLDEN])} suites x {kinds} digests, real and fixture data, in "
          f"{time.perf_counter() - t0:.1f} s")
    files = {path: golden.load(path) if path.is_file() else {"suites": {}, "benchmark_version": None}
             for path in digests}
    pinned = files[golden.GOLDEN_FILE]

    def diff_from(previous: bool) -> dict[str, list[str]]:
        """Suites whose pinned digests differ from the pinned ones, or from the previous version's (a
        digest the reference does not hold is an addition, not a change)."""
        out: dict[str, list[str]] = {}
        for path, doc in files.items():
            ref = (doc.get("previous") or {"suites": {}}) if previous else doc
            for eid, parts in golden.differences(digests[path], ref, new=False).items():
                out.setdefault(eid, parts)
        return out

    diff = diff_from(previous=False)
    added = {eid: parts for path, doc in files.items() if doc["suites"]
             for eid, parts in golden.additions(digests[path], doc).items()}
    same_version = pinned["benchmark_version"] == BENCHMARK_VERSION

    if not (args.bump or args.amend or args.write):
        if diff or not same_version:
            print(f"episodes differ from the pinned {pinned.get('benchmark')}: {changed_suites(diff)}; pin them as a "
                  "new version with --bump X.Y --note '...'")
            return 1
        if added:
            print(f"digests not pinned yet: {changed_suites(added)}; no pinned episode changed: pin them with "
                  "--write (an additive amendment of this version, docs/versions.md)")
            return 1
        print(f"the episodes are {pinned['benchmark']}'s, as pinned")
        return 0
    if args.write and diff and same_version and pinned["suites"]:
        raise SystemExit(f"pin_episodes: {changed_suites(diff)} differ from the pinned {BENCHMARK} "
                         f"{BENCHMARK_VERSION}: changed episodes are a new version (--bump X.Y --note ...), or "
                         "--amend before a release")
    if args.bump:
        if parse_version(args.bump) <= parse_version(BENCHMARK_VERSION):
            raise SystemExit(f"pin_episodes: --bump {args.bump} must be above the current {BENCHMARK_VERSION}")
        if not diff:
            raise SystemExit(f"pin_episodes: no suite's episodes differ from {BENCHMARK} {BENCHMARK_VERSION}: "
                             "nothing to bump")
        set_version(args.bump)
        add_doc_section(args.bump, args.note, diff)
        version = args.bump
        previous = {path: {"benchmark_version": doc["benchmark_version"], "suites": doc["suites"]}
                    for path, doc in files.items()}
    else:
        version = BENCHMARK_VERSION
        previous = {path: doc.get("previous") for path, doc in files.items()}
        if args.amend:
            amend_doc_section(version, args.note, diff_from(previous=True))
    for path, ds in digests.items():
        doc = {**golden.document(ds), "benchmark": f"{BENCHMARK} {version}", "benchmark_version": version}
        golden.write(path, {**doc, "previous": previous[path]} if previous[path] else doc)
        print(f"wrote {path.relative_to(ROOT)} ({BENCHMARK} {version})")
    if args.bump:
        print(f"set BENCHMARK_VERSION = {version!r} in {VERSION_FILE.relative_to(ROOT)}; added its section to "
              f"{VERSIONS_DOC.relative_to(ROOT)}: check the wording, and add a CHANGELOG.md line")
    return 0


if __name__ == "__main__":
    sys.exit(main())
