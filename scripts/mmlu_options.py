"""Which of an MMLU-Pro question's ten options are MMLU's own four (for RSB-General-4).

MMLU-Pro took 6,810 of its questions from MMLU and added six options to MMLU's four. The added
options carry words that mark them as distractors (a word model picks the answer among a random
four of the ten about a third of the time, chance a quarter); MMLU's four were written by people
for the question. RSB-General-4 shows them. This script finds them by matching each MMLU-derived
question (``src`` "ori_mmlu-*") to MMLU's release by normal form, and writes, per question, the
hashes of MMLU's three distractors (``mmlu_pro.option_hash``) to
rsb_maniskill/semantic/mmlu_pro_mmlu_options.txt, which the package ships: pools need no MMLU copy
at run time. Run it before scripts/filter_general.py (the filter reads what General-4 shows).

    python scripts/mmlu_options.py --mmlu-dir DIR [--data-dir DIR]

DIR holds MMLU in its original release layout (``<split>/<subject>_<split>.csv``, no header:
question, A, B, C, D, answer letter), as the ``data.tar`` of Hendrycks et al. unpacks.
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from rsb_maniskill.semantic import mmlu_pro
from rsb_maniskill.semantic.data import MMLU_PRO_REPO, MMLU_PRO_REVISION, mmlu_pro_rows
from rsb_maniskill.semantic.normalize import option_key, question_key
from rsb_maniskill.semantic.records import normalize_text


def mmlu_fours(root: Path) -> dict[str, list[list[str]]]:
    """MMLU question normal form -> the four-option lists of its rows (a question may repeat)."""
    files = sorted(root.glob("*/*.csv"))
    if not files:
        raise SystemExit(f"mmlu_options: no <split>/<subject>_<split>.csv files under {root}")
    out: dict[str, list[list[str]]] = {}
    for f in files:
        with open(f, encoding="utf-8", newline="") as fh:
            for row in csv.reader(fh):
                if len(row) == 6:
                    out.setdefault(question_key(normalize_text(row[0])), []).append(row[1:5])
    return out


def own_distractors(row: dict, fours: dict[str, list[list[str]]]) -> list[str] | None:
    """Hashes of MMLU's three distractors of an MMLU-Pro row, or None if MMLU's four are not all
    among its ten (or the question is not MMLU's)."""
    opts = [normalize_text(o) for o in row["choices"]]
    keys = [option_key(o) for o in opts]
    for four in fours.get(question_key(normalize_text(row["question"])), []):
        idx = [keys.index(k) if k in keys else -1 for k in (option_key(normalize_text(o)) for o in four)]
        if -1 not in idx and row["answer"] in idx and len(set(idx)) == 4:
            return sorted(mmlu_pro.option_hash(opts[i]) for i in idx if i != row["answer"])
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mmlu-dir", required=True, type=Path)
    ap.add_argument("--data-dir", default=None, help="MMLU-Pro (else $RSB_DATA_DIR, else the hub cache)")
    ap.add_argument("--out", default=str(mmlu_pro.MMLU_OPTIONS))
    args = ap.parse_args(argv)

    fours = mmlu_fours(args.mmlu_dir)
    rows, _ = mmlu_pro.eligible(mmlu_pro_rows(args.data_dir))
    from_mmlu = [r for r in rows if str(r.get("src", "")).startswith("ori_mmlu-")]
    found = {mmlu_pro.content_key(r): own for r in from_mmlu if (own := own_distractors(r, fours))}
    out = Path(args.out)
    header = (f"# RSB-General-4: MMLU's own distractors of MMLU-Pro ({MMLU_PRO_REPO}@{MMLU_PRO_REVISION[:12]}) "
              f"questions taken from MMLU, by scripts/mmlu_options.py\n# content key, then the option hashes of "
              f"MMLU's three distractors; {len(found):,} of {len(from_mmlu):,} eligible MMLU-derived questions\n")
    out.write_text(header + "".join(f"{k} {' '.join(v)}\n" for k, v in sorted(found.items())), encoding="utf-8")
    print(f"wrote {out}: MMLU's four found for {len(found):,} of {len(from_mmlu):,} eligible MMLU-derived "
          "questions", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
