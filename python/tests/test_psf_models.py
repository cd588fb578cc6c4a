import json

import numpy as np
import pytest
from PIL import Image

import pipeline
from conftest import FIXTURE, ROOT


@pytest.mark.parametrize("args,kwargs", [
    (["--psi", "0:8:5"], {"psi": "0:8:5"}),
    (["--psi", "-2,0,3.5"], {"psi": [-2, 0, 3.5], "camera": "conventional"}),
    (["--window", "9"], {"window": 9}),
    (["--window", "7", "--camera", "focus_sweep"], {"window": 7, "camera": "focus_sweep"}),
])
def test_psf_equals_the_cli_npy(cli, tmp_path, args, kwargs):
    out = tmp_path / "psf.npy"
    cam = ["--camera", kwargs["camera"]] if "camera" in kwargs and "--camera" not in args else []
    cli("psf", *args, *cam, "--out", out)
    want = np.load(out)
    got = pipeline.psf(**kwargs)
    assert got.dtype == np.float32 and got.ndim == 4 and got.shape[-1] == 3
    np.testing.assert_array_equal(got, want)


def test_psf_refuses_bad_values():
    with pytest.raises(ValueError, match="camera"):
        pipeline.psf(camera="pinhole")
    with pytest.raises(ValueError, match="psi 99"):
        pipeline.psf(psi=[99])
    with pytest.raises(ValueError, match="start:stop:count"):
        pipeline.psf(psi="0:8")


def to_8bit(x):
    """As `pipeline deblur` quantises: clamp, scale by 255 in float32, round half away from zero."""
    v = np.clip(x, 0, 1).astype(np.float32) * np.float32(255)
    r = np.rint(v)
    tie = v - np.floor(v) == 0.5
    r[tie] = np.floor(v[tie]) + 1
    return r.astype(np.uint8)


def test_deblur_matches_the_cli_and_exported_weights_keep_their_tensors(cli, tmp_path):
    ds = pipeline.CodedBlurDataset([ROOT / "fixtures" / "mandelbrot-pan-240fps.mp4"],
                                   overrides={"sources.video.max_frames": 9, "transforms.noise.sigma": 6.0})
    lq, gt, _ = next(iter(ds))
    out = pipeline.deblur(lq)
    assert out.shape == lq.shape and np.isfinite(out).all() and not np.array_equal(out, lq)
    # uint8 codes are the same image (they gave values from -206 to 212 before); a string array is refused.
    np.testing.assert_allclose(pipeline.deblur(np.rint(lq * 255).astype(np.uint8)), pipeline.deblur(np.rint(lq * 255) / 255), atol=1e-6)
    with pytest.raises(ValueError, match="dtype"):
        pipeline.deblur(np.zeros((3, 8, 8), dtype="U1"))
    # The CLI on the same 8-bit image (one tile) gives the same 8-bit output.
    Image.fromarray(np.rint(lq * 255).astype(np.uint8).transpose(1, 2, 0)).save(tmp_path / "in.png")
    cli("deblur", tmp_path / "in.png", "-o", tmp_path / "out.png", "--progress", "never")
    want = np.asarray(Image.open(tmp_path / "out.png")).transpose(2, 0, 1)
    np.testing.assert_array_equal(to_8bit(out), want)
    # Exported with PyTorch names: the shipped model's tensors, renamed.
    cli("export", ROOT / "models" / "unet32-coded", "-o", tmp_path / "unet32.safetensors")
    tensors, meta = pipeline.load_safetensors(tmp_path / "unet32.safetensors")
    assert meta["format"] == "pt" and '"base":32' in meta["arch"]
    assert tensors["inc.a.0.weight"].shape == (32, 3, 3, 3) and tensors["outc.bias"].shape == (3,)
    # 3,698,979 learned values plus 3,968 BatchNorm running statistics, as models/README.md counts.
    assert sum(v.size for k, v in tensors.items() if not k.endswith("num_batches_tracked")) == 3_702_947
    assert sum(v.size for k, v in tensors.items() if "running" not in k and "num_batches" not in k) == 3_698_979


def test_deblur_burst_matches_the_cli_frame_for_frame(cli, tmp_path):
    ds = pipeline.CodedBlurDataset([ROOT / "fixtures" / "mandelbrot-pan-240fps.mp4"], overrides={"sources.video.max_frames": 9})
    lq, _, _ = next(iter(ds))
    lq8 = np.rint(lq * 255).astype(np.uint8)
    burst = pipeline.deblur_burst(lq8, k=5)
    assert burst.shape == (5,) + lq.shape and burst.dtype == np.float32
    assert burst.min() >= 0.0 and burst.max() <= 1.0
    # The frames differ over the exposure (the network is told the time).
    assert np.abs(burst[0] - burst[4]).mean() > 1e-3
    # `pipeline deblur --burst 5` on the same 8-bit image writes the same frames.
    Image.fromarray(lq8.transpose(1, 2, 0)).save(tmp_path / "cap.png")
    cli("deblur", tmp_path / "cap.png", "-o", tmp_path / "out", "--burst", "5", "--progress", "never")
    for k in range(5):
        want = np.asarray(Image.open(tmp_path / "out" / "cap" / f"{k:02d}.png")).transpose(2, 0, 1)
        np.testing.assert_array_equal(to_8bit(burst[k]), want)
    with pytest.raises(ValueError, match="2 to 64"):
        pipeline.deblur_burst(lq8, k=1)
    with pytest.raises(ValueError, match="camera"):
        pipeline.deblur_burst(lq8, camera="flutter")


def test_evaluate_scores_what_the_cli_scores(cli, tmp_path):
    sets = {"eval.windows": [9], "eval.sigmas": [3.0], "eval.windows_per_video": 2, "eval.crop": 96, "eval.examples": 0}
    r = pipeline.evaluate(FIXTURE, tmp_path / "py", overrides=sets)
    assert r["model"] and len(r["records"]) == 2
    args = [a for k, v in sets.items() for a in ("--set", f"{k}={v}")]
    cli("eval", FIXTURE, "-o", tmp_path / "cli", "--progress", "never", *args)
    want = json.loads((tmp_path / "cli" / "eval.json").read_text())
    got = json.loads((tmp_path / "py" / "eval.json").read_text())
    assert got == r
    for a, b in zip(r["records"], want["records"]):
        assert a["deblurred"] == b["deblurred"] and a["blurred"] == b["blurred"], (a, b)
    # The report is kept unless asked to overwrite it; a bad key is named.
    with pytest.raises(ValueError, match="eval.json"):
        pipeline.evaluate(FIXTURE, tmp_path / "py", overrides=sets)
    pipeline.evaluate(FIXTURE, tmp_path / "py", overrides=sets, overwrite=True, camera="conventional")
    with pytest.raises(ValueError, match="sigmaz"):
        pipeline.evaluate(FIXTURE, tmp_path / "bad", overrides={"eval.sigmaz": [3.0]})


def test_exported_model_in_torch_matches_deblur(cli, tmp_path):
    torch = pytest.importorskip("torch")
    from pipeline.models import load

    for name in ["unet32-coded", "shallow32-coded"]:
        path = tmp_path / f"{name}.safetensors"
        cli("export", ROOT / "models" / name, "-o", path)
        net = load(path).eval()
        x = np.random.default_rng(0).random((3, 64, 96), dtype=np.float32)
        with torch.no_grad():
            y = net(torch.from_numpy(x)[None])[0].numpy()
        np.testing.assert_allclose(y, pipeline.deblur(x, model=ROOT / "models" / name), atol=1e-4, err_msg=name)
    # Sides that are not multiples of 16 (640x360): padded and cropped back like `pipeline deblur`.
    net = load(tmp_path / "unet32-coded.safetensors").eval()
    x = np.random.default_rng(1).random((3, 360, 640), dtype=np.float32)
    with torch.no_grad():
        y = net(torch.from_numpy(x)[None])[0].numpy()
    assert y.shape == (3, 360, 640)
    np.testing.assert_allclose(y, pipeline.deblur(x, model=ROOT / "models" / "unet32-coded"), atol=1e-4)


def test_type_stubs_name_every_export_with_the_real_parameters():
    import ast
    import inspect

    stub = ast.parse((ROOT / "python" / "pipeline" / "__init__.pyi").read_text())
    defs = {n.name: n for n in stub.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    assert set(pipeline.__all__) - {"__version__"} <= set(defs), set(pipeline.__all__) - set(defs)

    def params(node):
        return [a.arg for a in node.args.args if a.arg != "self"]

    for name in ["psf", "deblur", "to_torch", "load_safetensors"]:
        assert params(defs[name]) == list(inspect.signature(getattr(pipeline, name)).parameters), name
    init = next(n for n in defs["CodedBlurDataset"].body if isinstance(n, ast.FunctionDef) and n.name == "__init__")
    assert params(init) == list(inspect.signature(pipeline.CodedBlurDataset.__init__).parameters)[1:]
