"""The dataset card (``README.md``) of a built dataset, so ``huggingface-cli upload`` publishes it as is.

The YAML header is what the hub reads: licence, task categories, tags, the parquet files for its
viewer (``configs``, as LeRobot's own cards have them) and the features. ``dataset_info.features``
holds the parquet columns in the hub's (``datasets``') form, which the viewer checks against the
files; the camera streams are mp4 files beside the parquet, not columns of it, so they are listed
under ``video_features`` (name, dtype ``video``, shape, codec, fps). The text says what the data is,
how it was made, and how to train on it.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def _skipped(skipped: list[int], attempts: int) -> str:
    """The card's line on questions without a demo: how many, and why (the attempt limit)."""
    if not skipped:
        return f"0 (up to {attempts} seeds were tried per question)"
    shown = ", ".join(map(str, skipped[:10])) + (", ..." if len(skipped) > 10 else "")
    return f"{len(skipped)}: the expert failed on all {attempts} seeds tried for each (questions {shown})"


def _size_category(n: int) -> str:
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M")):
        if n < limit:
            return name
    return "1M<n<10M"


def hub_features(features: dict[str, dict]) -> tuple[list[dict], list[dict]]:
    """LeRobot ``info.json`` features as the hub's YAML header holds them: the parquet columns in
    ``datasets``' form (a scalar column ``dtype``, a fixed-length vector ``list`` + ``length``, as
    ``datasets.Features._to_yaml_list`` writes the data files' schema), and the videos."""
    columns, videos = [], []
    for name, ft in features.items():
        shape = list(ft["shape"])
        if ft["dtype"] == "video":
            info = ft.get("info") or {}
            videos.append({"name": name, "dtype": "video", "shape": shape, "names": ft.get("names"),
                           "codec": info.get("video.codec"), "fps": info.get("video.fps")})
        elif shape == [1]:
            columns.append({"name": name, "dtype": ft["dtype"]})
        elif len(shape) == 1:
            columns.append({"name": name, "list": ft["dtype"], "length": shape[0]})
        else:
            raise ValueError(f"feature {name}: shape {shape} has no column form here")
    return columns, videos


def _header(meta: dict[str, Any]) -> str:
    """The YAML header (between ``---`` lines) of ``meta`` (PyYAML comes with huggingface_hub)."""
    import yaml

    body = yaml.safe_dump(meta, sort_keys=False, default_flow_style=False, allow_unicode=True, width=1000)
    return "---\n" + body.rstrip("\n") + "\n---"


def dataset_card(dataset: str | Path, settings: dict[str, Any]) -> str:
    """The card of the dataset at ``dataset`` (its meta/ is read), built with ``settings``."""
    from rsb_maniskill.export.lerobot import INFO_FILE
    from rsb_maniskill.export.naming import camera_key
    from rsb_maniskill.objects.family import FAMILIES, split_env_id
    from rsb_maniskill.robot import CAMERAS
    from rsb_maniskill.semantic.suites import parse_suite_id, suite_source
    from rsb_maniskill.version import benchmark_label

    dataset = Path(dataset)
    info = json.loads((dataset / INFO_FILE).read_text())
    env_id = settings["env_id"]
    suite_id, targets = split_env_id(env_id)
    family, n_choices = parse_suite_id(suite_id)
    source, licence = suite_source(family).card, suite_source(family).licence
    repo = f"<your-hf-user>/{env_id.lower()}"
    cameras = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    skipped = settings.get("skipped_questions") or []
    columns, videos = hub_features(info["features"])
    header = _header({
        "license": licence.lower(),
        "task_categories": ["robotics"],
        "tags": ["LeRobot", "robosemanticbench", "maniskill", "aloha", "vision-language-action", env_id.lower()],
        "pretty_name": f"RoboSemanticBench {env_id} ({settings['split']})",
        "size_categories": [_size_category(info["total_frames"])],
        "configs": [{"config_name": "default", "data_files": "data/*/*.parquet"}],
        "dataset_info": {"features": columns},
        "video_features": videos,
    })
    body = f"""
# RoboSemanticBench: {env_id}, {settings['split']} split

Expert demonstrations of the RoboSemanticBench (RSB) task **{env_id}** as a LeRobot dataset (format
{info['codebase_version']}), made with `rsb_maniskill` {settings['rsb_version']} on ManiSkill 3: the episodes
of benchmark version **{benchmark_label(settings['benchmark_version'])}** (a result is comparable with results
of the same version only).
A dual-arm Aloha-AgileX robot sees {n_choices} candidate {FAMILIES[targets].described}
and a gray answer zone; the instruction holds a multiple-choice question whose options are bound to
the candidates, and the robot places the candidate of the correct answer in the zone. Each
episode's instruction is its task string.

| | |
|---|---|
| suite | {env_id} ({n_choices} choices, {targets}) |
| split | {settings['split']} (disjoint from the evaluation split's questions) |
| question source | {source} |
| questions | {settings['questions']} of a pool of {settings['pool_size']}; one demonstration each |
| benchmark version | {benchmark_label(settings['benchmark_version'])} (`rsb --version`; docs/versions.md) |
| episodes / frames | {info['total_episodes']} / {info['total_frames']} at {info['fps']} fps |
| questions without a demo | {_skipped(skipped, settings['max_attempts'])} |
| cameras | {', '.join(f"`{c}`" for c in cameras)} |
| state / action | `observation.state`, `action`: Aloha 14 numbers [left arm 6, left gripper, right arm 6, \
right gripper], grippers in [0, 1] (absolute joint targets) |
| seeds | question q is episode seed q (+ k x pool size after k failed attempts); `rsb/seed` per episode |

Per-episode RSB metadata is in `meta/episodes` (`rsb/question`, `rsb/options` (a list of strings),
`rsb/correct_letter`, `rsb/correct_option`, `rsb/target_block`, `rsb/seed`, ...), with `rsb/rationale`: a
short worked solution ending on the option and its block, ready as a chain-of-thought target;
`meta/rsb_build.json` holds the build settings.

## How it was made

`rsb_maniskill` is installed from a checkout of its repository (it is not on PyPI):
`bash scripts/setup.sh` there makes `.venv` with the package, its pins and, on machines without
an NVIDIA GPU, Mesa's software Vulkan driver; then, in that checkout:

```bash
.venv/bin/rsb dataset build --suites {env_id} --split {settings['split']} --questions {settings['questions']} \\
    --fps {settings['fps']} --cameras {','.join(settings['cameras'])} --naming {settings['naming']} --out DIR
```

A scripted motion-planning expert (mplib) grasps the correct candidate and places it in the zone;
only successful episodes are kept; camera frames are rendered from the recorded simulator states.

## Train on it

LeRobot (`lerobot-train`), e.g. a policy from its hub or a small ACT:

```bash
lerobot-train --dataset.repo_id={repo} --policy.type=act --output_dir=outputs/act-{env_id.lower()}
# or from a local copy: --dataset.repo_id=local/{env_id.lower()} --dataset.root=/path/to/this/folder
```

openpi: a LeRobot data config (`LeRobotAlohaDataConfig`) with `repo_id="{repo}"`; the camera keys are
openpi's Aloha names when built with `--naming rsb` ({', '.join(f"`{camera_key(c, 'rsb')}`" for c in CAMERAS)}).

Evaluate with the benchmark's protocol (its held-out evaluation episodes of each suite): `rsb eval` or, from
LeRobot, `lerobot-eval --env.type=rsb --env.task={env_id}`.

## Features

```json
{json.dumps(info['features'], indent=1)}
```
"""
    return header + "\n" + body
