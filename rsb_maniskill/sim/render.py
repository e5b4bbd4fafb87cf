"""Picks a Vulkan driver before SAPIEN starts, keeps one render engine alive per process, and
turns "no renderer" into a clear error.

On machines without a GPU Vulkan driver, SAPIEN needs Mesa's software driver (lavapipe) at
24.3 or newer (it uses VK_KHR_external_semaphore_fd). Where both a GPU and lavapipe drivers are
installed the Vulkan loader chooses itself, so we only pin lavapipe when no NVIDIA driver exists.

Render engine: every SAPIEN render object made while no render system is alive (URDF link
materials, block and zone materials, letter textures) starts a Vulkan instance of its own, and
with ``render_backend="none"`` nothing else keeps one alive. NVIDIA drivers refuse new instances
after a few dozen (``vk::createInstanceUnique: ErrorIncompatibleDriver`` from the third env on);
lavapipe doesn't, but its loader log shows the same churn. :func:`hold_render_engine` makes one
render system at first need (not at import: imports stay light and work without Vulkan) and
keeps it for the life of the process, so every later render object reuses its instance.

Software rendering shares the CPUs: lavapipe starts one raster thread per CPU in every process, so
local worker processes each cap it to their share (:func:`limit_lavapipe_threads`).

Library log lines (:func:`library_log_policy`, set at import, before ManiSkill loads, in every
process: workers import the package first): shown once per process, as plain text, only when
they matter. ManiSkill's "Requested to use render device sapien_cuda ... Rendering might be
disabled" is not shown: it comes at every env made on a machine without CUDA, also where nothing
renders (``-o state``), and where rendering fails the env's error says so, with the fix.

Stdlib only at import: ``rsb doctor`` loads this file on its own, without the package.
"""
from __future__ import annotations

import glob
import logging
import os
import subprocess
import sys

ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d",
            "/usr/local/nvidia/share/vulkan/icd.d")
_PROBE = "import sapien; sapien.render.RenderSystem(); print('ok')"
_PROBE_ENV = "RSB_RENDERER_OK"  # inherited by worker processes so that they skip the probe

FIX = ("Install a Vulkan driver: an NVIDIA driver on GPU machines, or Mesa lavapipe >= 24.3 "
       "without one (Debian 12: `apt-get install -t bookworm-backports mesa-vulkan-drivers`; "
       "`bash scripts/setup.sh` does this). State-only use needs no renderer: pass "
       "obs_mode='state' and render_backend='none'. `rsb doctor` shows what this machine has.")
_HELD: dict[str, object] = {}  # "engine" -> the process's render system (None: none could be made)
MANISKILL_LOGGER = "mani_skill "  # the name of ManiSkill's logger (mani_skill.utils.logging_utils), its space too
NOT_SHOWN = ("Rendering might be disabled", "is not installed with git")  # log lines that never matter here


class RendererUnavailableError(RuntimeError):
    """No Vulkan device that SAPIEN can render with."""


def renderer_hint(message: str) -> str | None:
    """What to do about an error that says the renderer is missing (SAPIEN's "failed to find a
    rendering device", a Vulkan error), in one sentence naming ``rsb doctor``; None for other errors."""
    text = message.lower()
    if not ("vulkan" in text or "rendering device" in text or "render device" in text):
        return None
    for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):
        value = os.environ.get(var)
        missing = [f for f in (value or "").split(os.pathsep) if f and not os.path.exists(f)]
        if missing:
            return (f"{var}={value} names no file ({missing[0]}): unset it or point it at a Vulkan ICD json "
                    f"(e.g. {ICD_DIRS[0]}/lvp_icd.x86_64.json); `rsb doctor` shows what this machine has")
    return "no Vulkan renderer: `rsb doctor` shows what this machine has and how to fix it"


def select_vulkan_driver() -> str | None:
    """Points the Vulkan loader at lavapipe when no NVIDIA driver is installed; returns the ICD used."""
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES")
    icds = [f for d in ICD_DIRS for f in sorted(glob.glob(os.path.join(d, "*.json")))]
    if any("nvidia" in os.path.basename(f) for f in icds):
        return None
    lavapipe = [f for f in icds if _is_lavapipe(f)]
    if lavapipe:
        os.environ["VK_ICD_FILENAMES"] = lavapipe[0]
        return lavapipe[0]
    return None


def _is_lavapipe(icd: str) -> bool:
    return os.path.basename(icd).startswith("lvp")


def software_rendering() -> bool:
    """True when this process renders with Mesa's lavapipe (the Vulkan driver picked above)."""
    return _is_lavapipe(select_vulkan_driver() or "")


def limit_lavapipe_threads(threads: int | None) -> bool:
    """Caps lavapipe's rasterizer threads in this process (Mesa's ``LP_NUM_THREADS``); True if set.

    lavapipe starts one raster thread per CPU in every process, so N worker processes on N cores
    would run N x N threads fighting for the cores; each worker takes its share instead. Must run
    before this process's first Vulkan instance (lavapipe reads the variable then); left alone when
    the user has set it, and on GPU drivers."""
    if not threads or "LP_NUM_THREADS" in os.environ or not software_rendering():
        return False
    os.environ["LP_NUM_THREADS"] = str(threads)
    return True


def lavapipe_share(workers: int) -> int:
    """Raster threads per worker when ``workers`` local processes share the CPUs this process may use."""
    from rsb_maniskill.parallel.threads import cpu_share  # affinity and cgroup quota, as --num-procs auto counts

    return cpu_share(workers)


def ensure_renderer() -> None:
    """Raises :class:`RendererUnavailableError` with a fix if SAPIEN cannot render here.

    The probe runs in a subprocess because a broken Vulkan stack can crash rather than raise."""
    if os.environ.get(_PROBE_ENV) == "1":
        _quiet_fallback_warning()
        return
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired as err:
        raise RendererUnavailableError(f"The Vulkan renderer did not start within 120 s. {FIX}") from err
    if out.returncode != 0 or "ok" not in out.stdout:
        detail = (out.stderr.strip().splitlines() or [f"exit code {out.returncode}"])[-1]
        raise RendererUnavailableError(f"SAPIEN found no usable Vulkan device ({detail}). {FIX}")
    os.environ[_PROBE_ENV] = "1"
    _quiet_fallback_warning()


def _quiet_fallback_warning() -> None:
    """Rendering works here (checked): ManiSkill's "Rendering might be disabled" would mislead."""
    try:
        from rsb_maniskill.compat import quiet_cpu_render_fallback
    except ImportError:  # `rsb doctor` loads this file without the package
        return
    quiet_cpu_render_fallback()


def hold_render_engine(device: object | None = None) -> bool:
    """Makes (once) and keeps the process's SAPIEN render system; True if one is held.

    ``device`` is the env's render device (a ``sapien.Device``); None (``render_backend="none"``)
    means the device ManiSkill renders on by default, so that later envs with a renderer use the
    same one: SAPIEN's render engine is one per process and serves one device. Where no Vulkan
    device exists nothing is held and state-only envs behave as before."""
    if "engine" not in _HELD:
        import sapien

        try:
            if device is None:
                from mani_skill.envs.utils.system.backend import parse_sim_and_render_backend

                from rsb_maniskill.env_ids import CPU_SIM_BACKEND

                device = parse_sim_and_render_backend(CPU_SIM_BACKEND, "gpu").render_device
            _HELD["engine"] = sapien.render.RenderSystem(device)
            _quiet_fallback_warning()  # it renders: the next envs' "might be disabled" would mislead
        except Exception:  # no usable Vulkan device here; rendering would fail the same way later
            _HELD["engine"] = None
    return _HELD["engine"] is not None


class _LogPolicy(logging.Filter):
    """Drops the lines of :data:`NOT_SHOWN` and any line this process has shown already."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if any(phrase in message for phrase in NOT_SHOWN) or message in self.seen:
            return False
        self.seen.add(message)
        return True


def library_log_policy() -> None:
    """ManiSkill's log lines as :class:`_LogPolicy` lets them through, plain (``ManiSkill WARNING:
    ...``: no colour codes, no time stamp). Set before ManiSkill loads, its logger then has a handler
    and ManiSkill adds no coloured one of its own; set after, its handlers lose the colour."""
    logger = logging.getLogger(MANISKILL_LOGGER)
    if any(isinstance(f, _LogPolicy) for f in logger.filters):
        return
    logger.addFilter(_LogPolicy())
    plain = logging.Formatter("ManiSkill %(levelname)s: %(message)s")
    if not logger.handlers:
        logger.addHandler(logging.StreamHandler())
    for handler in logger.handlers:
        handler.setFormatter(plain)


library_log_policy()
select_vulkan_driver()
