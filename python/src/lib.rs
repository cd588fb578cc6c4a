//! `pipeline._native`: the Rust side of the Python package. The Python layer
//! (`python/pipeline/__init__.py`) wraps it; nothing here is meant to be called directly.
//!
//! - `Stream`: a pipeline's samples in this process, through the same code `pipeline generate`
//!   runs ([`pipeline::graph::SampleStream`]), this task's share of the inputs.
//! - `psf`: the PSF stack `pipeline psf --out x.npy` writes.

use numpy::{IntoPyArray, PyArray3, PyArray4, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use pipeline::graph::{Next, SampleStream};
use pipeline::optics::request::PsfSpec;
use pipeline::sample::{Img, Pair, Sample};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

/// The process that started rayon's worker threads (0: none yet).
static POOL_PID: AtomicU32 = AtomicU32::new(0);

/// Refuses work in a process forked after this library started its threads in the parent (a
/// fork copies no threads, so rayon's pool would wait forever): a clear error instead of a hang.
fn fork_guard() -> PyResult<()> {
    let me = std::process::id();
    match POOL_PID.compare_exchange(0, me, Ordering::SeqCst, Ordering::SeqCst) {
        Ok(_) => Ok(()),
        Err(p) if p == me => Ok(()),
        Err(p) => Err(PyRuntimeError::new_err(format!(
            "pipeline: this process was forked from process {p} after pipeline had started its worker threads there, \
             and a fork copies no threads (the work would wait forever). Start DataLoader workers with \
             multiprocessing_context=\"spawn\" (or \"forkserver\"), or do not iterate a dataset, call psf() or \
             deblur() in the parent before the workers start"
        ))),
    }
}

/// The plan `pipeline generate` would run with these arguments, every error named.
fn plan(paths: &[String], config: Option<&std::path::Path>, sets: &[String]) -> PyResult<pipeline::config::Plan> {
    let (table, origin) = pipeline::config::generate_table(config, paths, sets).map_err(value_err)?;
    pipeline::config::plan_from(table, &origin).map_err(value_err)
}

/// Checks the settings and lists every input (sorted, as tasks share them out) without
/// starting a thread, so a DataLoader's forked workers start clean.
#[pyfunction]
#[pyo3(signature = (paths, config, sets))]
fn check(paths: Vec<String>, config: Option<std::path::PathBuf>, sets: Vec<String>) -> PyResult<Vec<String>> {
    let plan = plan(&paths, config.as_deref(), &sets)?;
    let inputs = pipeline::graph::list_inputs(&plan).map_err(value_err)?;
    if inputs.is_empty() {
        return Err(PyValueError::new_err("no input: the paths name no file the pipeline's source reads"));
    }
    Ok(inputs.iter().map(|(i, _)| i.path.clone()).collect())
}

/// The crate's error with its whole chain, as the CLI prints it (`{:#}`).
fn chain(e: pipeline::Error) -> String {
    format!("{:#}", anyhow::Error::from(e))
}

/// Bad settings, no input: Python's ValueError.
fn value_err(e: pipeline::Error) -> PyErr {
    PyValueError::new_err(chain(e))
}

/// One pair ready for Python: CHW planes (u8, converted to f32 on the Python thread only when
/// asked) and the sample's JSON.
struct Ready {
    w: usize,
    h: usize,
    lq: Vec<u8>,
    /// The target, or a burst's K targets one after another (K x CHW).
    gt: Vec<u8>,
    /// How many targets `gt` holds: 0 for one image (3, H, W), K for a burst (K, 3, H, W).
    burst: usize,
    /// The sample's key and its `key.json` text.
    key: String,
    meta: String,
}

/// Interleaved RGB8 to planar (CHW).
fn planar(rgb: &[u8], w: usize, h: usize) -> Vec<u8> {
    let n = w * h;
    let mut out = vec![0u8; 3 * n];
    for (i, px) in rgb.chunks_exact(3).enumerate() {
        out[i] = px[0];
        out[n + i] = px[1];
        out[2 * n + i] = px[2];
    }
    out
}

fn ready(s: &Sample, p: &Pair) -> Ready {
    let rgb = |img| Img::rgb8(img, p.w, p.h, s.curve);
    let (key, meta) = (pipeline::sample::sample_key(s, p), pipeline::sample::meta_json(s, p));
    Ready {
        w: p.w,
        h: p.h,
        lq: planar(&rgb(&p.lq), p.w, p.h),
        gt: if p.burst.is_empty() {
            planar(&rgb(&p.gt), p.w, p.h)
        } else {
            p.burst.iter().flat_map(|b| planar(&rgb(b), p.w, p.h)).collect()
        },
        burst: p.burst.len(),
        key,
        meta: String::from_utf8(meta).expect("JSON is UTF-8"),
    }
}

/// `(lq, gt, key, meta_json)` as `__next__` returns it.
type PyPair<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>, String, String);

/// The samples of a pipeline over this task's inputs, pair by pair: `(lq, gt, key, meta_json)`
/// with `lq`/`gt` as (3, H, W) arrays, uint8 or float32 in [0, 1].
#[pyclass(module = "pipeline._native")]
struct Stream {
    inner: Option<SampleStream>,
    pending: VecDeque<Ready>,
    float: bool,
    raise_on_failure: bool,
    failed: Vec<(String, String)>,
}

#[pymethods]
impl Stream {
    /// paths: videos, folders or globs (empty: the pipeline's own paths); config: a pipeline
    /// file (None: the embedded pipelines/generate.toml); sets: `key=value` overrides;
    /// task: (index, count) share of the sorted inputs.
    #[new]
    #[pyo3(signature = (paths, config, sets, task_index, task_count, float32 = true, on_failure = "raise"))]
    fn new(
        paths: Vec<String>,
        config: Option<std::path::PathBuf>,
        sets: Vec<String>,
        task_index: usize,
        task_count: usize,
        float32: bool,
        on_failure: &str,
    ) -> PyResult<Stream> {
        let raise_on_failure = match on_failure {
            "raise" => true,
            "warn" => false,
            o => return Err(PyValueError::new_err(format!("on_failure={o:?}: expected \"raise\" or \"warn\""))),
        };
        let plan = plan(&paths, config.as_deref(), &sets)?;
        fork_guard()?;
        let inner = SampleStream::open(&plan, (task_index, task_count)).map_err(value_err)?;
        Ok(Stream { inner: Some(inner), pending: VecDeque::new(), float: float32, raise_on_failure, failed: Vec::new() })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<PyPair<'py>>> {
        loop {
            if let Some(r) = self.pending.pop_front() {
                let (lq, gt) = (self.array(py, r.lq, 0, r.h, r.w)?, self.array(py, r.gt, r.burst, r.h, r.w)?);
                return Ok(Some((lq, gt, r.key, r.meta)));
            }
            let Some(inner) = self.inner.as_mut() else { return Ok(None) };
            // Wait without the GIL, a tenth of a second at a time, so Ctrl-C reaches Python.
            let next = py.detach(|| inner.next(Duration::from_millis(100)));
            match next {
                Ok(Next::Sample(s)) => self.pending.extend(s.pairs.iter().map(|p| ready(&s, p))),
                Ok(Next::Failed(path, why)) => {
                    // The error names the input itself.
                    let why = why.to_string();
                    self.failed.push((path, why.clone()));
                    if self.raise_on_failure {
                        self.inner = None;
                        return Err(PyRuntimeError::new_err(why));
                    }
                    let warnings = py.import("warnings")?;
                    warnings.call_method1("warn", (format!("pipeline: input failed, skipped: {why}"),))?;
                }
                Ok(Next::Waiting) => py.check_signals()?,
                Ok(Next::End) => {
                    self.inner = None;
                    return Ok(None);
                }
                Err(e) => {
                    self.inner = None;
                    return Err(PyRuntimeError::new_err(chain(e)));
                }
            }
        }
    }

    /// Inputs that failed so far: (path, reason).
    #[getter]
    fn failed(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }

    /// Stops every stage now (also done when the stream is garbage-collected).
    fn close(&mut self) {
        self.inner = None;
        self.pending.clear();
    }
}

impl Stream {
    /// A (3, H, W) array, or (K, 3, H, W) for `k` > 0 images, that owns the buffer it was made
    /// from (no copy for uint8).
    fn array<'py>(&self, py: Python<'py>, chw: Vec<u8>, k: usize, h: usize, w: usize) -> PyResult<Bound<'py, PyAny>> {
        if self.float {
            let f: Vec<f32> = chw.iter().map(|&v| f32::from(v) / 255.0).collect();
            let a = f.into_pyarray(py);
            return Ok(if k == 0 { a.reshape([3, h, w])?.into_any() } else { a.reshape([k, 3, h, w])?.into_any() });
        }
        let a = chw.into_pyarray(py);
        if k == 0 {
            let a: Bound<'py, PyArray3<u8>> = a.reshape([3, h, w])?;
            Ok(a.into_any())
        } else {
            Ok(a.reshape([k, 3, h, w])?.into_any())
        }
    }
}

/// The PSF stack `pipeline psf --out x.npy` writes: (K, H, W, 3) float32, RGB last.
#[pyfunction]
#[pyo3(signature = (camera = "phase_coded", psi = None, window = None, config = None, airy_radius_px = None, psi_spec = None))]
fn psf<'py>(
    py: Python<'py>,
    camera: &str,
    psi: Option<Vec<f64>>,
    window: Option<u16>,
    config: Option<std::path::PathBuf>,
    airy_radius_px: Option<f64>,
    psi_spec: Option<String>,
) -> PyResult<Bound<'py, PyArray4<f32>>> {
    // "start:stop:count" or "a,b,c", read by the CLI's own parser (same values as --psi).
    let psi = match psi_spec {
        Some(s) => Some(pipeline::optics::request::parse_psi_list(&s).map_err(|e| PyValueError::new_err(format!("psi {s:?}: {e}")))?),
        None => psi,
    };
    let kind = serde_json::from_value(serde_json::Value::String(camera.into()))
        .map_err(|e| PyValueError::new_err(format!("camera {camera:?}: {e}")))?;
    let spec = PsfSpec {
        camera: kind,
        psi,
        window: window.map(usize::from),
        config,
        airy_radius_px,
        spectrum: None,
        dispersion: None,
        defocus_sign: None,
    };
    fork_guard()?;
    let (shape, data) = py
        .detach(|| {
            let (optics, camera, req) = pipeline::optics::request::resolve(&spec)?;
            let rows = pipeline::optics::request::compute(&optics, &camera, &req)?;
            Ok::<_, pipeline::Error>(pipeline::optics::request::to_hwc(&rows))
        })
        .map_err(value_err)?;
    data.into_pyarray(py).reshape([shape[0], shape[1], shape[2], shape[3]])
}

/// A trained network (`pipeline deblur`'s fast CPU path) on one (3, H, W) float32 image in
/// [0, 1]; the raw output (input + residual), not clamped. `model`: a file or folder written by
/// `pipeline train` or `pipeline export`; None: the embedded default.
#[pyfunction]
#[pyo3(signature = (image, model = None))]
fn deblur<'py>(
    py: Python<'py>,
    image: PyReadonlyArray3<'py, f32>,
    model: Option<std::path::PathBuf>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (c, h, w) = (image.shape()[0], image.shape()[1], image.shape()[2]);
    if c != 3 {
        return Err(PyValueError::new_err(format!("image of shape ({c}, {h}, {w}): expected (3, H, W)")));
    }
    let data = image.as_slice().map_err(|_| PyValueError::new_err("image must be C-contiguous"))?.to_vec();
    fork_guard()?;
    let out = py
        .detach(|| {
            // The last model stays loaded: deblurring image after image does not reload it.
            static LAST: std::sync::Mutex<Option<(Option<std::path::PathBuf>, std::sync::Arc<pipeline::model::fast::FastNet>)>> =
                std::sync::Mutex::new(None);
            let net = {
                let mut last = LAST.lock().expect("model cache");
                match &*last {
                    Some((p, net)) if *p == model => net.clone(),
                    _ => {
                        let net = std::sync::Arc::new(pipeline::model::infer::load(model.as_deref())?.0);
                        *last = Some((model.clone(), net.clone()));
                        net
                    }
                }
            };
            Ok::<_, pipeline::Error>(net.forward(&pipeline::model::fast::T4::new(1, 3, h, w, data)).d)
        })
        .map_err(value_err)?;
    out.into_pyarray(py).reshape([3, h, w])
}

/// `pipeline deblur --burst K` on one (3, H, W) float32 image in [0, 1]: K sharp frames in time
/// order, (K, 3, H, W) float32 clamped to [0, 1], the network run in tiles as the command runs
/// it. `camera` picks the shipped burst model of that camera when `model` is None.
#[pyfunction]
#[pyo3(signature = (image, k = 9, model = None, camera = None))]
fn deblur_burst<'py>(
    py: Python<'py>,
    image: PyReadonlyArray3<'py, f32>,
    k: usize,
    model: Option<std::path::PathBuf>,
    camera: Option<String>,
) -> PyResult<Bound<'py, PyArray4<f32>>> {
    use pipeline::optics::CameraKind;
    let (c, h, w) = (image.shape()[0], image.shape()[1], image.shape()[2]);
    if c != 3 {
        return Err(PyValueError::new_err(format!("image of shape ({c}, {h}, {w}): expected (3, H, W)")));
    }
    if !(2..=64).contains(&k) {
        return Err(PyValueError::new_err(format!("k = {k}: the number of frames per capture must be 2 to 64")));
    }
    let camera = match camera.as_deref() {
        None | Some("phase_coded") => None,
        Some("conventional") => Some(CameraKind::Conventional),
        Some(other) => return Err(PyValueError::new_err(format!("camera {other:?}: expected \"phase_coded\" or \"conventional\""))),
    };
    let data = image.as_slice().map_err(|_| PyValueError::new_err("image must be C-contiguous"))?.to_vec();
    fork_guard()?;
    let outs = py
        .detach(|| {
            let (net, _) = pipeline::model::infer::load_for(model.as_deref(), camera, true)?;
            let times: Vec<f32> = (0..k).map(|i| (i as f32 + 0.5) / k as f32).collect();
            let tiling = pipeline::model::infer::Tiling::default();
            Ok::<_, pipeline::Error>(pipeline::model::infer::deblur_planes(&net, &data, w, h, tiling, Some(&times)))
        })
        .map_err(value_err)?;
    outs.concat().into_pyarray(py).reshape([k, 3, h, w])
}

/// `pipeline eval` (the single-frame scores of a model on high-frame-rate videos): writes
/// `eval.json`, `eval.md` and `examples/` under `out` and returns `eval.json`'s text. `sets`:
/// `key=value` overrides of `pipelines/eval.toml`; `camera`: the camera the videos are blurred
/// with (its shipped model when `model` is None). An existing report is kept unless `overwrite`.
#[pyfunction]
#[pyo3(signature = (videos, out, model = None, camera = None, sets = Vec::new(), overwrite = false))]
fn evaluate(
    py: Python<'_>,
    videos: Vec<String>,
    out: std::path::PathBuf,
    model: Option<std::path::PathBuf>,
    camera: Option<String>,
    sets: Vec<String>,
    overwrite: bool,
) -> PyResult<String> {
    use pipeline::commands::eval::{run, EvalFile, EVAL_TOML};
    let origin = "pipelines/eval.toml (embedded)";
    let camera = camera
        .map(|c| {
            serde_json::from_value::<pipeline::optics::CameraKind>(serde_json::Value::String(c.clone()))
                .map_err(|_| PyValueError::new_err(format!("camera {c:?}: not a camera kind (phase_coded, conventional, ...)")))
        })
        .transpose()?;
    fork_guard()?;
    py.detach(|| {
        pipeline::io::paths::refuse_replacing(&out, &[out.join("eval.json"), out.join("eval.md")], overwrite)?;
        let table = pipeline::config::parse(EVAL_TOML, origin, &sets)?;
        let (f, net, name) = EvalFile::with_model(table, origin, camera, model.as_deref(), false)?;
        let r = run(&f, &net, &name, &videos, &out, pipeline::progress::ProgressMode::Never)?;
        Ok::<_, pipeline::Error>(serde_json::to_string(&r).expect("json"))
    })
    .map_err(value_err)
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Stream>()?;
    m.add_function(wrap_pyfunction!(psf, m)?)?;
    m.add_function(wrap_pyfunction!(deblur, m)?)?;
    m.add_function(wrap_pyfunction!(deblur_burst, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(check, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
