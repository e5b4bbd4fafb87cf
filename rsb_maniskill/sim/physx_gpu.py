"""SAPIEN's PhysX GPU library: where it lives, fetching it while there is network, and a clear
error instead of a download that hangs.

GPU physics (``sim_backend="physx_cuda"``, or ``num_envs > 1``) needs ``libPhysXGpu_64.so``, which
no package registry carries. SAPIEN's ``physx.enable_gpu()`` fetches it from GitHub at first use
with ``requests.get`` and no timeout: on a compute node without internet that is a traceback, or
behind a firewall that drops packets, a hang. ``scripts/setup.sh`` stages it on NVIDIA machines
(``python -m rsb_maniskill.sim.physx_gpu``); RSB envs call :func:`check_for_sim_backend` first.

Run as a module: prints where the library is, fetching it first if it is missing.
"""
from __future__ import annotations

import io
import os
import platform
import sys
from pathlib import Path

from rsb_maniskill.network import OFFLINE_VARS, offline

CONNECT_TIMEOUT = 5.0  # s to reach GitHub before giving up
READ_TIMEOUT_VAR = "RSB_NETWORK_TIMEOUT"  # s between bytes of the download (default 30)
SETUP_COMMAND = "python -m rsb_maniskill.sim.physx_gpu"


class PhysXGpuLibraryMissing(RuntimeError):
    """GPU physics was asked for, the PhysX GPU library is not installed and can't be fetched."""


def physx_version() -> str:
    import sapien

    return sapien.physx.version()


def library_path() -> Path:
    """Where SAPIEN looks for the library: ``~/.sapien/physx/<physx version>/libPhysXGpu_64.so``."""
    name = "PhysXGpu_64.dll" if platform.system() == "Windows" else "libPhysXGpu_64.so"
    return Path.home() / ".sapien" / "physx" / physx_version() / name


def library_url() -> str:
    """The release archive SAPIEN downloads for this platform."""
    system, machine = platform.system(), platform.machine()
    if system == "Windows":
        archive = "windows-dll.zip"
    elif system == "Linux" and machine in ("aarch64", "arm64"):
        archive = "linux-aarch64-so.zip"
    else:
        archive = "linux-so.zip"
    return f"https://github.com/sapien-sim/physx-precompiled/releases/download/{physx_version()}/{archive}"


def _missing(reason: str) -> PhysXGpuLibraryMissing:
    lib = library_path()
    return PhysXGpuLibraryMissing(
        f"GPU physics (sim_backend='physx_cuda') needs SAPIEN's PhysX GPU library {lib}, which is not "
        f"installed and could not be fetched: {reason}. On a machine with network run `{SETUP_COMMAND}` "
        f"(scripts/setup.sh does it on NVIDIA machines), or download {library_url()} and unzip it into "
        f"{lib.parent}/ (copy that directory to offline nodes). CPU physics needs none of this: "
        f"sim_backend='physx_cpu', num_envs=1. `rsb doctor` shows what this machine has.")


def fetch(timeout: float | None = None) -> Path:
    """The library's path, downloading and unzipping it first if it is missing (no network call
    when it is present). Raises :class:`PhysXGpuLibraryMissing` offline or when GitHub can't be
    reached within seconds."""
    lib = library_path()
    if lib.is_file():
        return lib
    if offline():
        raise _missing(f"offline ({' or '.join(OFFLINE_VARS)} is set)")
    import zipfile

    import requests

    read = float(os.environ.get(READ_TIMEOUT_VAR, "30")) if timeout is None else timeout
    try:
        res = requests.get(library_url(), timeout=(min(CONNECT_TIMEOUT, read), read))
        res.raise_for_status()
        archive = zipfile.ZipFile(io.BytesIO(res.content))
    except (requests.RequestException, zipfile.BadZipFile) as err:
        raise _missing(f"{type(err).__name__}: {err}") from None
    lib.parent.mkdir(parents=True, exist_ok=True)
    archive.extractall(lib.parent)
    if not lib.is_file():
        raise _missing(f"the archive from {library_url()} holds no {lib.name}")
    return lib


def uses_gpu_physics(sim_backend: str, num_envs: int) -> bool:
    """Whether a ManiSkill env with these arguments runs PhysX on the GPU (as BaseEnv decides)."""
    name = str(sim_backend or "auto").split(":")[0].lower()
    if name == "auto":
        return int(num_envs) > 1
    return name in ("physx_cuda", "gpu") or name.startswith("cuda")


def check_for_sim_backend(sim_backend: str, num_envs: int) -> None:
    """Before a GPU-physics env is built: have the library, or raise the clear error."""
    if not uses_gpu_physics(sim_backend, num_envs):
        return
    import sapien

    if not sapien.physx.is_gpu_enabled():
        fetch()


def gpu_physics_unavailable(probe_network: bool = True) -> str | None:
    """Why GPU physics (``physx_cuda``, ``num_envs > 1``) can't run on this machine now, or None
    when it can: the one rule the GPU-physics tests skip by and ``rsb doctor`` reports.

    It needs a CUDA device and the library. A missing library is fetched at the first GPU env, so
    it counts against GPU physics only where it can't be: offline, or (``probe_network``) when
    GitHub does not answer within seconds. Without ``probe_network`` (``rsb doctor``: no network)
    a missing library is reason enough."""
    import torch

    from rsb_maniskill.network import unreachable

    if not torch.cuda.is_available():
        return "GPU physics (sim_backend='physx_cuda') needs a CUDA device, and torch sees none"
    if library_path().is_file():
        return None
    if offline():
        return str(_missing(f"offline ({' or '.join(OFFLINE_VARS)} is set)"))
    if not probe_network:
        lib = library_path()
        return (f"GPU physics (sim_backend='physx_cuda') needs SAPIEN's PhysX GPU library {lib}, which is not "
                f"installed yet: it is fetched at the first GPU env if GitHub answers; `{SETUP_COMMAND}` fetches it "
                f"now, or download {library_url()} and unzip it into {lib.parent}/")
    why = unreachable(library_url())
    return None if why is None else str(_missing(why))


def main() -> int:
    try:
        lib = fetch()
    except PhysXGpuLibraryMissing as err:
        print(f"physx_gpu: {err}", file=sys.stderr)
        return 1
    print(f"PhysX GPU library: {lib}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
