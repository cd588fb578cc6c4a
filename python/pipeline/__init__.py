"""pipeline: motion deblurring with a spatiotemporally phase-coded camera, from Python.

The coded-blur generator of the ``pipeline`` command-line tool as a dataset that streams
training pairs into a training loop (no shards on disk), the camera's PSFs, and (with torch
installed) the U-Net and shallow networks with the weights ``pipeline export`` writes.

    from pipeline import CodedBlurDataset
    ds = CodedBlurDataset(["clips/"], overrides={"transforms.noise.sigma": [0, 9]}, seed=0)
    for lq, gt, meta in ds:          # lq, gt: float32 (3, 128, 128) in [0, 1], encoded sRGB
        ...

Only NumPy is required; torch is used when it is installed.
"""

import importlib.util
import json
import os

from . import _native
from ._native import __version__
from .safetensors import load_safetensors

__all__ = ["CodedBlurDataset", "psf", "deblur", "deblur_burst", "evaluate", "to_torch", "load_safetensors", "__version__"]

# CodedBlurDataset is a torch IterableDataset when torch is installed (so DataLoader takes it
# as one and shards it across its workers), a plain iterable otherwise.
if importlib.util.find_spec("torch") is not None:
    from torch.utils.data import IterableDataset as _Base
else:
    _Base = object


def _toml(value):
    """A Python value as a TOML literal for a ``--set key=value`` override."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"override value {value!r}: expected a number, string, bool, list or dict")


def _sets(overrides):
    """``{"key.path": value}`` overrides as ``--set key.path=value`` strings."""
    return [f"{k}={_toml(v)}" for k, v in (overrides or {}).items()]


def _worker():
    """(worker id, number of workers) of the torch DataLoader worker we run in, else (0, 1)."""
    if importlib.util.find_spec("torch") is None:
        return 0, 1
    from torch.utils.data import get_worker_info

    info = get_worker_info()
    return (0, 1) if info is None else (info.id, info.num_workers)


def _rank():
    """(rank, world size): torch.distributed when it is initialised, else RANK/WORLD_SIZE, else (0, 1)."""
    if importlib.util.find_spec("torch") is not None:
        import torch.distributed as dist

        if dist.is_available() and dist.is_initialized():
            return dist.get_rank(), dist.get_world_size()
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))


class CodedBlurDataset(_Base):
    """Coded-blur training pairs made on the fly by the same code as ``pipeline generate``.

    Iterating yields ``(lq, gt, meta)``: ``lq`` the blurred (and noisy) input, ``gt`` the sharp
    target, both (3, H, W) arrays in [0, 1] (``dtype="float32"``, encoded as the pipeline's
    curve, sRGB by default) or 0 to 255 (``dtype="uint8"``, exactly the PNG pixels ``pipeline
    generate`` writes); ``meta`` is the dict the shards carry as ``key.json`` plus ``key``.

    Bursts (``overrides={"transforms.blur.burst": True}``): ``gt`` is the whole burst, a
    (K, 3, H, W) array of the sharp images at the times ``meta["times"]`` lists (the shards'
    ``key.gt.00.png`` ...); with ``burst="each"`` the dataset yields ``(lq, t, gt_at_t, meta)``
    once per time instead.

    paths:      videos, folders of videos or globs (None: the pipeline file's own paths).
    config:     a pipeline file (None: the pipelines/generate.toml built into the package).
    overrides:  ``{"transforms.blur.window": 11, "transforms.noise.sigma": [0, 9]}``, as
                ``pipeline generate --set``.
    seed:       the pipeline's seed (None: the file's). The same seed gives the same pairs.
    on_failure: "raise" (default) stops at an input that cannot be read; "warn" skips it
                with a warning (pairs it gave before failing are not taken back).
    rank, world_size: this process's share in distributed training (default: torch.distributed
                when initialised, else the RANK and WORLD_SIZE variables, else 0 and 1).

    With DataLoader workers started by fork (Linux's default), do not iterate a dataset or call
    psf() or deblur() in the parent first: a fork copies no threads, and the workers then stop
    with an error saying so. ``multiprocessing_context="spawn"`` has no such limit.

    Inputs are shared out whole: input i (of the sorted list) goes to task
    ``i % (world_size * workers)``, where task = rank * workers + DataLoader worker id, as
    ``pipeline generate --shard-index/--shard-count`` does. So every pair comes exactly once
    over all ranks and workers; with one worker and one rank, in the order ``pipeline generate``
    writes them. Tasks beyond the number of inputs get none: give at least as many inputs as
    ``world_size * num_workers``.
    """

    def __init__(self, paths=None, config=None, overrides=None, seed=None, dtype="float32", on_failure="raise",
                 rank=None, world_size=None, burst="all"):
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        self.paths = [os.fspath(p) for p in (paths or [])]
        for p in self.paths:
            # A missing file or folder fails here, named once, not when first iterated.
            if p != "-" and not any(c in p for c in "*?[") and not os.path.exists(p):
                raise FileNotFoundError(f"{p}: no such file or folder")
        self.config = None if config is None else os.fspath(config)
        self.overrides = dict(overrides or {})
        if seed is not None:
            self.overrides["seed"] = int(seed)
        if dtype not in ("float32", "uint8"):
            raise ValueError(f"dtype={dtype!r}: expected 'float32' or 'uint8'")
        self.dtype = dtype
        if on_failure not in ("raise", "warn"):
            raise ValueError(f"on_failure={on_failure!r}: expected 'raise' or 'warn'")
        self.on_failure = on_failure
        self.rank, self.world_size = rank, world_size
        if burst not in ("all", "each"):
            raise ValueError(f"burst={burst!r}: expected 'all' (the whole burst as gt) or 'each' ((lq, t, gt_at_t, meta) per time)")
        self.burst = burst
        # (path, reason) of inputs that failed in the last iteration in this process (a
        # DataLoader worker's list stays in the worker; its warning reaches the log).
        self.failed = []
        # Check the settings and list the inputs now (every error named, in the caller rather
        # than in a worker), without starting a thread: DataLoader's forked workers start clean.
        self._inputs = _native.check(self.paths, self.config, _sets(self.overrides))

    def _stream(self, index, count):
        return _native.Stream(self.paths, self.config, _sets(self.overrides), index, count, self.dtype == "float32", self.on_failure)

    def task(self):
        """(task index, task count) of the calling process and DataLoader worker."""
        worker, workers = _worker()
        rank, world = _rank()
        if self.rank is not None:
            rank = self.rank
        if self.world_size is not None:
            world = self.world_size
        if not 0 <= rank < world:
            raise ValueError(f"rank {rank} must be below world_size {world}")
        return rank * workers + worker, world * workers

    def inputs(self):
        """The inputs the calling process and worker read, in order."""
        index, count = self.task()
        return [p for i, p in enumerate(self._inputs) if i % count == index]

    def __iter__(self):
        stream = self._stream(*self.task())
        try:
            for lq, gt, key, meta in stream:
                m = json.loads(meta)
                m["key"] = key
                if self.burst == "each" and "times" in m:
                    for t, g in zip(m["times"], gt):
                        yield lq, t, g, m
                else:
                    yield lq, gt, m
        finally:
            self.failed = stream.failed
            stream.close()


def psf(camera="phase_coded", psi=None, window=None, config=None, airy_radius_px=None):
    """The PSF stack ``pipeline psf --out x.npy`` writes: (K, H, W, 3) float32, RGB last.

    psi: defocus values (radians at the pupil rim, 455 nm), a list or ``"start:stop:count"``
    (default 0:8:9); window: instead, the N sub-frame kernels of one exposure window of
    ``camera``; config: a TOML file with [optics] / [camera] tables.
    """
    spec = psi if isinstance(psi, str) else None  # parsed by the CLI's own parser
    if psi is not None and spec is None:
        psi = [float(p) for p in psi]
    return _native.psf(camera, None if spec else psi, window, None if config is None else os.fspath(config), airy_radius_px, spec)


def _image(image):
    """A (3, H, W) image as contiguous float32 in [0, 1]; integer pixels are the codes of their type."""
    import numpy as np

    a = np.asarray(image)
    if a.ndim != 3 or a.shape[0] != 3:
        raise ValueError(f"image of shape {a.shape}: expected (3, H, W)")
    if a.dtype.kind in "ui":
        # Integer pixels are the codes of their type (0 to 255 for uint8), not values in [0, 1].
        a = a.astype(np.float32) / float(np.iinfo(a.dtype).max)
    elif a.dtype.kind != "f":
        raise ValueError(f"image of dtype {a.dtype}: expected float in [0, 1] or integer codes (uint8, uint16)")
    return np.ascontiguousarray(a, dtype=np.float32)


def deblur(image, model=None):
    """Runs a trained network (``pipeline deblur``'s fast CPU path) on one image.

    image: (3, H, W) float in [0, 1], encoded sRGB (uint8 or uint16 codes are scaled to it); model: a model file or folder written by
    ``pipeline train`` or ``pipeline export`` (None: the default coded U-Net; the last model used
    stays loaded, so a file rewritten under the same path is not read again). Returns the
    network's (3, H, W) float32 output, not clamped or quantised.
    """
    return _native.deblur(_image(image), None if model is None else os.fspath(model))


def deblur_burst(image, k=9, model=None, camera=None):
    """``pipeline deblur --burst K`` on one capture: K sharp frames over the exposure, in time order.

    image: (3, H, W) float in [0, 1] (or uint8/uint16 codes), a capture of the camera; k: frames
    (2 to 64, at times (i + 0.5) / k); model: a burst model file or folder (None: the shipped burst
    U-Net of ``camera``, "phase_coded" by default, or "conventional"). The network runs in tiles as
    the command runs it, and the part that does not depend on the time once. Returns (k, 3, H, W)
    float32 in [0, 1].
    """
    return _native.deblur_burst(_image(image), int(k), None if model is None else os.fspath(model), camera)


def evaluate(videos, out, model=None, camera=None, overrides=None, overwrite=False):
    """``pipeline eval``: a model's scores on high-frame-rate videos, as the command computes them.

    videos: files, folders or globs; out: the folder for ``eval.json``, ``eval.md`` and
    ``examples/`` (an existing report is kept unless ``overwrite``); model: a model file or folder
    (None: the shipped model of ``camera``); camera: the camera the windows are blurred with
    ("phase_coded" by default, "conventional", ...); overrides: ``{"eval.windows": [9]}``-style
    keys of ``pipelines/eval.toml``. Returns the report (``eval.json``) as a dict: ``table`` (per
    window length and sigma), ``per_spread``, ``records`` (every window), ...
    """
    if isinstance(videos, (str, os.PathLike)):
        videos = [videos]
    text = _native.evaluate([os.fspath(v) for v in videos], os.fspath(out),
                            None if model is None else os.fspath(model), camera, _sets(overrides), bool(overwrite))
    return json.loads(text)


def to_torch(sample):
    """A sample (or any nest of tuples, lists and dicts of arrays) with its arrays as torch tensors (no copy)."""
    import numpy as np
    import torch

    if isinstance(sample, np.ndarray):
        return torch.from_numpy(sample)
    if isinstance(sample, (tuple, list)):
        return type(sample)(to_torch(s) for s in sample)
    if isinstance(sample, dict):
        return {k: to_torch(v) for k, v in sample.items()}
    return sample
