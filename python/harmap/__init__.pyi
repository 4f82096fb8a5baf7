"""Type hints of the harmap package (see harmap/__init__.py for the docstrings)."""

import os
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
Mem = Union[str, int]
Shape = Union[
    PathLike,
    Tuple[npt.ArrayLike, npt.ArrayLike],
    npt.ArrayLike,
    Any,  # a mesh object with .vertices and .faces (trimesh), or a zarr array
    None,
]

class HarmapError(ValueError):
    """A stage failed; the message is the one the harmap command prints."""

    bad_input: bool

class Run:
    path: Path
    metadata: Dict[str, Any]
    pipeline: Optional[Dict[str, Any]]
    def __init__(self, path: PathLike) -> None: ...
    def __fspath__(self) -> str: ...
    def reload(self) -> "Run": ...
    @property
    def stages(self) -> Dict[str, Dict[str, Any]]: ...
    def report(self, stage: str) -> Dict[str, Any]: ...
    def done(self, stage: str) -> bool: ...
    @property
    def grid(self) -> Dict[str, Any]: ...
    @property
    def input(self) -> Dict[str, Any]: ...
    @property
    def labels(self) -> Any: ...
    @property
    def phi(self) -> Any: ...
    @property
    def theta(self) -> Any: ...
    @property
    def psi(self) -> Any: ...
    @property
    def u(self) -> Any: ...
    @property
    def seeds(self) -> Dict[str, np.ndarray]: ...
    def seeds_frame(self) -> Any: ...

def open(run: PathLike) -> Run: ...
def voxelize(
    shape: Shape = None,
    out: Optional[PathLike] = None,
    *,
    force: bool = False,
    resolution: Optional[int] = None,
    spacing: Optional[float] = None,
    padding: int = 6,
    center: Optional[Sequence[float]] = None,
    center_radius: float = 2.0,
    topology: Literal["auto", "repair", "strict"] = "auto",
    allow_genus: bool = False,
    keep_largest: bool = False,
    close: int = 0,
    unit: Optional[str] = None,
    chunk: int = 64,
    mem: Mem = "1GiB",
    scratch: Literal["auto", "memory", "disk"] = "auto",
    raw_shape: Optional[Sequence[int]] = None,
    raw_dtype: Optional[str] = None,
    surface: Literal["vdw", "sas", "ses"] = "ses",
    probe: Union[float, Sequence[float]] = 1.4,
    model: Optional[int] = None,
    keep_hetatm: bool = False,
    radius: Optional[float] = None,
    progress: bool = True,
) -> Run: ...
def solve(
    run: PathLike,
    *,
    method: Literal["multigrid", "sor", "jacobi"] = "multigrid",
    cycle: Literal["fmg", "v"] = "fmg",
    rtol: float = 1e-6,
    tol: float = 0.0,
    eps: float = 1e-4,
    max_iter: int = 1000,
    omega: Optional[float] = None,
    checkpoint_every: Union[str, float] = "5m",
    mem: Mem = "1GiB",
    resume: bool = False,
    progress: bool = True,
) -> Dict[str, Any]: ...
def trace(
    run: PathLike,
    *,
    seeds: Literal["surface", "boundary"] = "surface",
    sample: Optional[int] = None,
    stop_radius: Optional[float] = None,
    tile: Optional[int] = None,
    mem: Mem = "1GiB",
    atol: Optional[float] = None,
    rtol: float = 0.0,
    h_min: float = 1e-6,
    h_max: float = 2.0,
    max_steps: int = 20000,
    level_step: Optional[float] = None,
    untangle: bool = False,
    progress: bool = True,
) -> Dict[str, Any]: ...
def map(run: PathLike, *, exact: bool = False, mem: Mem = "1GiB", progress: bool = True) -> Dict[str, Any]: ...
def inverse(
    run: PathLike,
    phi: npt.ArrayLike,
    theta: npt.ArrayLike,
    psi: npt.ArrayLike,
    *,
    mem: Mem = "1GiB",
    progress: bool = True,
) -> Tuple[npt.NDArray[np.float64], List[str]]: ...
def export(
    run: PathLike,
    dest: PathLike,
    format: Literal["csv", "obj-sphere", "vtk-streamlines", "nifti", "vti", "dx", "ome-zarr"],
    *,
    field: Optional[Literal["phi", "theta", "psi", "labels"]] = None,
    sample: Optional[int] = None,
    mem: Mem = "1GiB",
    force: bool = False,
    progress: bool = True,
) -> int: ...
def atlas(
    run: PathLike,
    dest: PathLike,
    *,
    sphere: bool = False,
    color: Optional[Literal["axis", "z", "distance", "chain", "residue"]] = None,
) -> int: ...
def report(run: PathLike, dest: Optional[PathLike] = None) -> Path: ...
def run(
    shape: Shape = None,
    out: Optional[PathLike] = None,
    *,
    force: bool = False,
    resolution: Optional[int] = None,
    spacing: Optional[float] = None,
    padding: int = 6,
    center: Optional[Sequence[float]] = None,
    center_radius: float = 2.0,
    topology: Literal["auto", "repair", "strict"] = "auto",
    allow_genus: bool = False,
    keep_largest: bool = False,
    close: int = 0,
    unit: Optional[str] = None,
    chunk: int = 64,
    mem: Mem = "1GiB",
    scratch: Literal["auto", "memory", "disk"] = "auto",
    raw_shape: Optional[Sequence[int]] = None,
    raw_dtype: Optional[str] = None,
    surface: Literal["vdw", "sas", "ses"] = "ses",
    probe: Union[float, Sequence[float]] = 1.4,
    model: Optional[int] = None,
    keep_hetatm: bool = False,
    radius: Optional[float] = None,
    method: Literal["multigrid", "sor", "jacobi"] = "multigrid",
    cycle: Literal["fmg", "v"] = "fmg",
    rtol: float = 1e-6,
    tol: float = 0.0,
    eps: float = 1e-4,
    max_iter: int = 1000,
    omega: Optional[float] = None,
    checkpoint_every: Union[str, float] = "5m",
    seeds: Literal["surface", "boundary"] = "surface",
    sample: Optional[int] = None,
    stop_radius: Optional[float] = None,
    tile: Optional[int] = None,
    atol: Optional[float] = None,
    h_min: float = 1e-6,
    h_max: float = 2.0,
    max_steps: int = 20000,
    level_step: Optional[float] = None,
    untangle: bool = False,
    trace_rtol: float = 0.0,
    exact: bool = False,
    progress: bool = True,
) -> Run: ...
