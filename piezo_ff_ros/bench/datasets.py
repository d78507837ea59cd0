"""Loaders for the public datasets kept (read-only, never copied into this repository) in ``../shared/data``.

Each returns SI units (s, V, m; the Bouc-Wen benchmark's input is a force in N, said in ``meta['units']``) and keeps
the attribution of its ``SOURCE.md`` in ``meta['attribution']``:

- ``dbo_piezo_micromanipulator`` — Y. N. Aye, W. T. Ang, "A Discrete Backlash Operator for Identification and
  Compensation of Hysteresis and Non-linearity for Piezoelectric Micromanipulator", ICSTSD 2018; data from
  github.com/yan9a/DiscreteBacklashOperator (MIT, © 2019 Yan Naing Aye).  Single axis, 200 Hz.
- ``fsm_cubespec_piezo`` — M. Floren et al., "Data-driven state-space identification and nonlinearity assessment of
  the CubeSpec Fine Steering Mirror", ISMA-USD 2024; data github.com/merijnfloren/fsm-benchmark-data (CC BY 4.0,
  © 2025 Merijn Floren, KU Leuven).  3 inputs × 3 outputs, 6400 Hz, train/test split.
- ``boucwen_benchmark`` — J.P. Noël, M. Schoukens, "Hysteretic benchmark with a dynamic nonlinearity", Workshop on
  Nonlinear System Identification Benchmarks 2016 (doi:10.4121/12967592); synthetic, 750 Hz.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

import numpy as np

from ..core.recording.run import RunData
from ..core.units import UM

#: a dataset root: a path, or None for :func:`shared_data_dir`
PathLike = Union[str, "os.PathLike[str]"]

__all__ = ["shared_data_dir", "DboRuns", "load_dbo", "FsmLevel", "load_fsm", "load_boucwen_benchmark",
           "DBO_ATTRIBUTION", "FSM_ATTRIBUTION", "BOUCWEN_ATTRIBUTION"]

DBO_ATTRIBUTION = ("Y. N. Aye, W. T. Ang, ICSTSD 2018; data github.com/yan9a/DiscreteBacklashOperator "
                   "(MIT, (c) 2019 Yan Naing Aye)")
FSM_ATTRIBUTION = ("M. Floren, L. Peri, J. De Maeyer, W. De Munter, D. Vandepitte, J.P. Noel, ISMA-USD 2024, "
                   "pp. 2042-2052; data github.com/merijnfloren/fsm-benchmark-data (CC BY 4.0, (c) 2025 Merijn "
                   "Floren, KU Leuven); baseline models doi:10.5281/zenodo.19591136")
BOUCWEN_ATTRIBUTION = ("J.P. Noel, M. Schoukens, Hysteretic benchmark with a dynamic nonlinearity, Workshop on "
                       "Nonlinear System Identification Benchmarks 2016, doi:10.4121/12967592")


def shared_data_dir() -> Path:
    """``$PIEZO_FF_SHARED_DATA`` or ``<repo>/../shared/data``."""
    env = os.environ.get("PIEZO_FF_SHARED_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data"


def _dir(root: PathLike | None, name: str) -> Path:
    d = Path(root) if root is not None else shared_data_dir()
    d = d / name if (d / name).is_dir() else d
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: dataset folder not found")
    return d


# ----------------------------------------------------------------------------------------------------------------
# dbo_piezo_micromanipulator
# ----------------------------------------------------------------------------------------------------------------

@dataclass
class DboRuns:
    """The two recordings: ``model`` (1 Hz sine drive, for identification) and ``test`` (reference tracking).

    ``test.reference`` is the desired displacement (col 9); ``segments`` gives the upstream script's row windows
    (0-based, half-open) of the uncompensated and the compensated parts; ``delay`` is the sensor's one-sample lag.
    """

    model: RunData
    test: RunData
    segments: dict[str, Any]
    delay: int = 1


def load_dbo(root: PathLike | None = None) -> DboRuns:
    """Load ``Model_Vi_Do.dat`` and ``Test_Vi_Do_Di.dat`` (200 Hz) in SI: voltage col 1 [V], sensor col 5 [µm → m]."""
    d = _dir(root, "dbo_piezo_micromanipulator")
    fs = 200.0
    out = {}
    for key, fname in (("model", "Model_Vi_Do.dat"), ("test", "Test_Vi_Do_Di.dat")):
        a = np.loadtxt(d / fname)
        n = a.shape[0]
        t = np.arange(n) / fs
        ref = a[:, [8]] * UM if key == "test" else None
        out[key] = RunData(t=t, u=a[:, [0]].copy(), y=a[:, [4]] * UM, axes=("x",), reference=ref,
                           meta={"source": str(d / fname), "attribution": DBO_ATTRIBUTION,
                                 "units": {"u": "V", "y": "m"}, "dataset": "dbo_piezo_micromanipulator"})
    segments = {"model_cycle_start": 3151, "uncompensated": (3851, 5052), "compensated": (11151, 11852)}
    return DboRuns(model=out["model"], test=out["test"], segments=segments, delay=1)


# ----------------------------------------------------------------------------------------------------------------
# fsm_cubespec_piezo
# ----------------------------------------------------------------------------------------------------------------

@dataclass
class FsmLevel:
    """One amplitude level: arrays ``[n_samples=8192, 3, n_realizations, n_periods=2]`` in V and m."""

    level_mV: int
    u_train: np.ndarray
    y_train: np.ndarray
    u_test: np.ndarray
    y_test: np.ndarray
    fs: float = 6400.0
    attribution: str = FSM_ATTRIBUTION

    def runs(self, split: str = "train") -> list[RunData]:
        """One :class:`RunData` per realization (both periods concatenated; period 1 is the transient)."""
        u = self.u_train if split == "train" else self.u_test
        y = self.y_train if split == "train" else self.y_test
        out = []
        for r in range(u.shape[2]):
            uu = np.concatenate([u[:, :, r, p] for p in range(u.shape[3])])
            yy = np.concatenate([y[:, :, r, p] for p in range(y.shape[3])])
            out.append(RunData(t=np.arange(len(uu)) / self.fs, u=uu, y=yy, axes=("1", "2", "3"),
                               meta={"dataset": "fsm_cubespec_piezo", "level_mV": self.level_mV, "split": split,
                                     "realization": r, "attribution": self.attribution}))
        return out


def load_fsm(level_mV: int, root: PathLike | None = None) -> FsmLevel:
    """Load one amplitude level (100, 200 or 300 mV) of the CubeSpec FSM benchmark (already V and m)."""
    if level_mV not in (100, 200, 300):
        raise ValueError(f"level_mV: expected 100, 200 or 300, got {level_mV!r}")
    d = _dir(root, "fsm_cubespec_piezo")
    arr = {}
    for v in ("u", "y"):
        for s in ("train", "test"):
            a = np.load(d / f"{v}_{level_mV}mV_{s}.npy")
            if a.ndim != 4 or a.shape[1] != 3:
                raise ValueError(f"{d}/{v}_{level_mV}mV_{s}.npy: unexpected shape {a.shape}")
            arr[f"{v}_{s}"] = a
    return FsmLevel(level_mV, arr["u_train"], arr["y_train"], arr["u_test"], arr["y_test"])


# ----------------------------------------------------------------------------------------------------------------
# boucwen_benchmark
# ----------------------------------------------------------------------------------------------------------------

def load_boucwen_benchmark(root: PathLike | None = None) -> dict[str, RunData]:
    """Estimation (``estimation``) and validation (``multisine``, ``sinesweep``) runs; input force [N], y [m]."""
    import scipy.io

    d = _dir(root, "boucwen_benchmark")
    m = scipy.io.loadmat(str(d / "bouc-wen.mat"))
    fs = 750.0
    out = {}
    for key, (uk, yk) in {"estimation": ("u", "y"), "multisine": ("uval_multisine", "yval_multisine"),
                          "sinesweep": ("uval_sinesweep", "yval_sinesweep")}.items():
        u = np.asarray(m[uk], float).ravel()[:, None]
        y = np.asarray(m[yk], float).ravel()[:, None]
        out[key] = RunData(t=np.arange(len(u)) / fs, u=u, y=y, axes=("x",),
                           meta={"dataset": "boucwen_benchmark", "units": {"u": "N", "y": "m"},
                                 "attribution": BOUCWEN_ATTRIBUTION})
    return out
