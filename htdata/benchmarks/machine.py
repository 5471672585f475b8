"""The machine a benchmark ran on: CPUs, RAM, load, library versions, BLAS threading env."""

from __future__ import annotations

import os
import platform
import sys

from htdata.workers import usable_cores

BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_CORETYPE")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict:
    import cv2
    import numpy as np
    import psutil
    try:
        import torch
    except ModuleNotFoundError:      # a data-only install (no [bench] extra)
        torch = None

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {
        "cpu_count": os.cpu_count() or 1,
        "cpu_affinity": usable_cores(),
        "cpu_model": cpu_model(),
        "ram_gb": psutil.virtual_memory().total / 2**30,
        "loadavg_1m": float(load[0]),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "torch": torch.__version__ if torch else "not installed",
        "torch_threads": torch.get_num_threads() if torch else None,
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "blas_env": {k: os.environ.get(k, "unset") for k in BLAS_ENV},
    }
