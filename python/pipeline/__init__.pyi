# Type stubs of the `pipeline` package (PEP 561): what `import pipeline` offers.
import os
from typing import Any, Iterator, Mapping, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str
__all__: list[str]

_Path = Union[str, "os.PathLike[str]"]
_Sample = tuple[npt.NDArray[Any], npt.NDArray[Any], dict[str, Any]]

try:
    from torch.utils.data import IterableDataset as _Base
except ImportError:  # torch is optional
    _Base = object

class CodedBlurDataset(_Base):  # type: ignore[misc, valid-type]
    paths: list[str]
    config: str | None
    overrides: dict[str, Any]
    dtype: str
    on_failure: str
    rank: int | None
    world_size: int | None
    burst: str
    failed: list[tuple[str, str]]
    def __init__(
        self,
        paths: _Path | Sequence[_Path] | None = ...,
        config: _Path | None = ...,
        overrides: Mapping[str, Any] | None = ...,
        seed: int | None = ...,
        dtype: str = ...,
        on_failure: str = ...,
        rank: int | None = ...,
        world_size: int | None = ...,
        burst: str = ...,
    ) -> None: ...
    def task(self) -> tuple[int, int]: ...
    def inputs(self) -> list[str]: ...
    def __iter__(self) -> Iterator[_Sample]: ...

def psf(
    camera: str = ...,
    psi: str | Sequence[float] | None = ...,
    window: int | None = ...,
    config: _Path | None = ...,
    airy_radius_px: float | None = ...,
) -> npt.NDArray[np.float32]: ...
def deblur(image: npt.ArrayLike, model: _Path | None = ...) -> npt.NDArray[np.float32]: ...
def deblur_burst(
    image: npt.ArrayLike, k: int = ..., model: _Path | None = ..., camera: str | None = ...
) -> npt.NDArray[np.float32]: ...
def evaluate(
    videos: _Path | Sequence[_Path],
    out: _Path,
    model: _Path | None = ...,
    camera: str | None = ...,
    overrides: Mapping[str, Any] | None = ...,
    overwrite: bool = ...,
) -> dict[str, Any]: ...
def to_torch(sample: Any) -> Any: ...
def load_safetensors(path: _Path) -> tuple[dict[str, npt.NDArray[Any]], dict[str, str]]: ...
