import io
import json
import tarfile
import warnings

import numpy as np
import pytest
from PIL import Image

import pipeline
from conftest import FIXTURE

# A short run: 10 windows of 9 frames, 8 patches each.
SHORT = {"sources.video.max_frames": 90}


def read_shards(out):
    """(key, lq, gt, meta) of every sample in the shards of `out`, in the manifest's input order."""
    manifest = json.loads((out / "manifest.json").read_text())
    samples = []
    for entry in manifest["inputs"]:
        for shard in entry["shards"]:
            with tarfile.open(out / shard["name"]) as tar:
                files = {}
                for m in tar.getmembers():
                    key, ext = m.name.split(".", 1)
                    files.setdefault(key, {})[ext] = tar.extractfile(m).read()
                    if len(files[key]) == 3:
                        f = files[key]
                        png = lambda b: np.asarray(Image.open(io.BytesIO(b)).convert("RGB")).transpose(2, 0, 1)
                        samples.append((key, png(f["lq.png"]), png(f["gt.png"]), json.loads(f["json"])))
    return samples


def test_yields_the_pairs_generate_writes_in_its_order(cli, tmp_path):
    out = tmp_path / "out"
    cli("generate", FIXTURE, "-o", out, "--set", "sources.video.max_frames=90", "--set", "seed=3", "--progress", "never")
    shards = read_shards(out)
    assert len(shards) == 80
    ds = pipeline.CodedBlurDataset([FIXTURE], overrides=SHORT, seed=3, dtype="uint8")
    got = list(ds)
    assert [m["key"] for _, _, m in got] == [k for k, _, _, _ in shards]
    for (lq, gt, meta), (key, slq, sgt, smeta) in zip(got, shards):
        assert lq.dtype == np.uint8 and lq.shape == (3, 128, 128)
        np.testing.assert_array_equal(lq, slq, err_msg=key)
        np.testing.assert_array_equal(gt, sgt, err_msg=key)
        assert {k: v for k, v in meta.items() if k != "key"} == smeta
    # float32 is the same pixels in [0, 1]: byte-equal after 8-bit quantisation.
    lq, gt, meta = next(iter(pipeline.CodedBlurDataset([FIXTURE], overrides=SHORT, seed=3)))
    assert lq.dtype == np.float32 and meta["key"] == shards[0][0]
    np.testing.assert_array_equal(np.rint(lq * 255).astype(np.uint8), shards[0][1])
    np.testing.assert_array_equal(np.rint(gt * 255).astype(np.uint8), shards[0][2])
    # Another seed gives other pairs.
    other = next(iter(pipeline.CodedBlurDataset([FIXTURE], overrides=SHORT, seed=4, dtype="uint8")))
    assert not np.array_equal(other[0], shards[0][1])


def keys(ds):
    return [m["key"] for _, _, m in ds]


def test_workers_and_ranks_together_yield_every_sample_once(clips, monkeypatch):
    short = {"sources.video.max_frames": 27, "transforms.patches.per_window": 2}
    everything = keys(pipeline.CodedBlurDataset([clips], overrides=short, dtype="uint8"))
    assert len(everything) == 4 * 3 * 2 and len(set(everything)) == len(everything)
    seen = []
    for rank in range(2):
        for worker in range(2):
            # What torch.utils.data.get_worker_info() says inside DataLoader worker `worker` of 2.
            monkeypatch.setattr(pipeline, "_worker", lambda w=worker: (w, 2))
            ds = pipeline.CodedBlurDataset([clips], overrides=short, dtype="uint8", rank=rank, world_size=2)
            assert ds.task() == (rank * 2 + worker, 4)
            part = keys(ds)
            assert len(part) == 6, f"rank {rank} worker {worker}: one input each"
            seen += part
    assert sorted(seen) == sorted(everything)


def as_list(batch):
    return batch


def test_dataloader_workers_when_torch_is_installed(clips):
    torch = pytest.importorskip("torch")
    short = {"sources.video.max_frames": 27, "transforms.patches.per_window": 2}
    assert isinstance(pipeline.CodedBlurDataset([clips], overrides=short), torch.utils.data.IterableDataset)
    seen = []
    for rank in range(2):
        # Two real DataLoader workers in each of two simulated ranks. spawn: this test process
        # has run the pipeline already (its threads are not forked).
        ds = pipeline.CodedBlurDataset([clips], overrides=short, rank=rank, world_size=2)
        loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, collate_fn=as_list, multiprocessing_context="spawn")
        seen += [m["key"] for batch in loader for _, _, m in batch]
    assert sorted(seen) == sorted(keys(pipeline.CodedBlurDataset([clips], overrides=short)))
    lq, gt, _ = pipeline.to_torch(next(iter(pipeline.CodedBlurDataset([clips], overrides=short))))
    assert lq.dtype == torch.float32 and lq.shape == (3, 128, 128)


def test_bad_settings_and_inputs_are_named(tmp_path, clips):
    with pytest.raises(ValueError, match=r"transforms\.blur\.window"):
        pipeline.CodedBlurDataset([FIXTURE], overrides={"transforms.blur.window": "nine"})
    with pytest.raises(ValueError, match="no_such_stage|unknown"):
        pipeline.CodedBlurDataset([FIXTURE], overrides={"transforms.no_such_stage.x": 1})
    with pytest.raises(ValueError, match="on_failure"):
        pipeline.CodedBlurDataset([FIXTURE], on_failure="ignore")
    missing = tmp_path / "missing.mp4"
    with pytest.raises(FileNotFoundError) as e:
        pipeline.CodedBlurDataset([missing])
    assert str(e.value).count("missing.mp4") == 1, str(e.value)
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    with pytest.raises(RuntimeError, match="bad.mp4"):
        list(pipeline.CodedBlurDataset([bad, clips / "a.mp4"], overrides=SHORT))
    ds = pipeline.CodedBlurDataset([bad, clips / "a.mp4"], overrides=SHORT, on_failure="warn")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        n = len(list(ds))
    assert n == 80, "the good input's pairs all come"
    assert any("bad.mp4" in str(x.message) for x in w)
    assert [p for p, _ in ds.failed] == [str(bad)]


def test_a_process_forked_after_the_threads_started_gets_an_error_not_a_hang():
    import os

    pipeline.psf(psi=[0])  # this process now has its worker threads
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        try:
            pipeline.psf(psi=[0])
            os.write(w, b"ran")
        except RuntimeError as e:
            os.write(w, b"error: " + str(e).encode()[:400])
        os._exit(0)
    os.close(w)
    msg = os.read(r, 1000).decode()
    os.waitpid(pid, 0)
    assert msg.startswith("error: ") and "spawn" in msg and "forked" in msg, msg
