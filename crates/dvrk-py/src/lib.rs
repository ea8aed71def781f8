//! `dvrk_sidecar._native`: the compiled half of the `dvrk_sidecar` Python package.
//!
//! A [`dvrk_ipc::Subscription`] per topic, driven from Python: `NativeSubscription::wait`
//! runs the consumer's wait strategy (event, predictive, spin) in compiled code with the GIL
//! released, so other Python threads keep running while one waits, and hands the newest sample
//! to Python as one numpy array over the whole message (a structured dtype given by the Python
//! side, built from its ctypes layouts): one copy of the message into a new buffer (made while
//! the wait expects the sample, so the hand-off is the copy alone), then every field a view
//! of it.
//!
//! Python never sees this module directly: `dvrk_sidecar.Arm` uses it when it imports
//! (`dvrk_sidecar.BACKEND == "native"`) and falls back to the pure-Python client otherwise.

use std::rc::Rc;

use dvrk_ipc::iceoryx2::config::Config;
use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    ArmServices, CompensationStatusV4, IpcError, JawStateV1, JointStateV2, Message, PoseV2,
    ServiceNames, SubscribeOptions, Subscription, Topic, Update, WaitStrategy,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyByteArray, PyDict};

pyo3::create_exception!(
    _native,
    NativeError,
    PyRuntimeError,
    "A failure of dvrk-ipc or iceoryx2 (opening a service, receiving, waiting)."
);

fn native_err(e: impl std::fmt::Display) -> PyErr {
    NativeError::new_err(e.to_string())
}

/// Moves a `!Send` borrow into [`Python::detach`]'s closure.
///
/// Sound here: the closure runs synchronously on the calling thread (`detach` only releases
/// the GIL around it), and the borrowed subscription belongs to an `unsendable` pyclass, which
/// PyO3 lets no other thread touch, borrowed mutably for the whole call.
struct OnThisThread<T>(T);
// SAFETY: see above; the value never leaves the thread that created it.
unsafe impl<T> Send for OnThisThread<T> {}
impl<T> OnThisThread<T> {
    /// By value, so that a closure captures the whole wrapper, not its (`!Send`) field.
    fn into_inner(self) -> T {
        self.0
    }
}

/// The bytes of a message. Every [`Message`] is `repr(C)` of `u64`/`u32`/`f64` with no
/// implicit padding (checked at compile time in dvrk-ipc), so all its bytes are initialised.
fn bytes_of<T: Message>(v: &T) -> &[u8] {
    // SAFETY: `v` is a valid `T` of `size_of::<T>()` initialised bytes (no padding, see above),
    // borrowed for the returned lifetime.
    unsafe { core::slice::from_raw_parts((v as *const T).cast::<u8>(), core::mem::size_of::<T>()) }
}

fn seconds_to_ns(s: f64) -> u64 {
    if s.is_finite() && s > 0.0 {
        (s * 1e9).min(u64::MAX as f64) as u64
    } else {
        0
    }
}

/// An iceoryx2 node in the sidecar's domain (the default one, or an isolated one), shared by
/// the subscriptions of one `Arm`.
#[pyclass(unsendable, module = "dvrk_sidecar._native", name = "Node")]
struct NativeNode {
    node: Rc<Node<Service>>,
}

#[pymethods]
impl NativeNode {
    /// `domain`: the file-name prefix of an isolated domain (e.g. `"t123_"`), `root`: its root
    /// path (e.g. `"/tmp/iox2t/"`); `None` for the project's defaults
    /// (`dvrk_ipc::default_domain`: `dvrk_<euid>_` under `/tmp/dvrk-sidecar-<euid>/` or
    /// `$DVRK_SIDECAR_IPC_ROOT`), where `dvrk-sidecar serve` publishes. Same checks as
    /// `dvrk_ipc::domain_config`; in the default root, the same refusal of a directory that is
    /// not this account's alone (`dvrk_ipc::create_node`).
    #[new]
    #[pyo3(signature = (name = "dvrk-sidecar-python", domain = None, root = None))]
    fn new(name: &str, domain: Option<&str>, root: Option<&str>) -> PyResult<Self> {
        let prefix = domain.map_or_else(dvrk_ipc::default_domain_prefix, str::to_owned);
        let mut config = dvrk_ipc::domain_config(&prefix, root)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        leave_dead_nodes_to_the_sidecar(&mut config);
        let node = dvrk_ipc::create_node::<Service>(name, Some(&config)).map_err(native_err)?;
        Ok(Self {
            node: Rc::new(node),
        })
    }
}

/// Turns off iceoryx2's automatic removal of dead nodes (on node creation and destruction, and
/// on opening a service) for this module's nodes.
///
/// iceoryx2 tells a dead node by its monitor lock (`fcntl(F_GETLK)`) unless the node carries
/// this copy of iceoryx2's process id. A Python process may hold a second copy of iceoryx2
/// beside this module's: the `iceoryx2` package (the pure-Python client, or the lab's own
/// publishers). Its nodes carry another id, and `F_GETLK` never reports a lock of the asking
/// process, so this module saw them as dead and removed their services while they were in use
/// (a publisher in the same process was never heard). The sidecar removes the nodes of dead
/// processes every few seconds, and a subscription that hears nothing still reaps a dead
/// publisher of its own service ([`dvrk_ipc::Subscription`]).
fn leave_dead_nodes_to_the_sidecar(config: &mut Config) {
    config.global.node.cleanup_dead_nodes_on_creation = false;
    config.global.node.cleanup_dead_nodes_on_destruction = false;
    config.global.service.cleanup_dead_nodes_on_open = false;
}

/// The eleven services of one arm (`dvrk_ipc::ArmServices`), opened or created with the
/// project's QoS when an `Arm` is made, so that a service of another type or QoS is refused
/// then, by name, not when a getter first reads it. Holds no port.
#[pyclass(unsendable, module = "dvrk_sidecar._native", name = "ArmServices")]
struct NativeArmServices {
    _services: ArmServices<Service>,
    _node: Rc<Node<Service>>,
}

#[pymethods]
impl NativeArmServices {
    #[new]
    fn new(node: &NativeNode, prefix: &str) -> PyResult<Self> {
        let names = ServiceNames::new(prefix).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let services = ArmServices::open_or_create(&node.node, &names).map_err(|e| match e {
            // The same words as the pure client: the service, the type asked for, iceoryx2's
            // reason (`IncompatibleTypes` for a service of another type).
            IpcError::OpenService { service, source } => {
                let asked = ServiceNames::split(&service).map_or("?", |(_, t)| t.type_name());
                native_err(format!("opening {service} as {asked}: {source}"))
            }
            e => native_err(e),
        })?;
        Ok(Self {
            _services: services,
            _node: node.node.clone(),
        })
    }
}

enum Inner {
    Joint(Subscription<JointStateV2>),
    Jaw(Subscription<JawStateV1>),
    Pose(Subscription<PoseV2>),
    Status(Subscription<CompensationStatusV4>),
}

/// Runs `$body` with `$s` bound to the typed subscription, whatever its message type.
macro_rules! each_type {
    ($inner:expr, $s:ident => $body:expr) => {
        match $inner {
            Inner::Joint($s) => $body,
            Inner::Jaw($s) => $body,
            Inner::Pose($s) => $body,
            Inner::Status($s) => $body,
        }
    };
}

/// What one call of the underlying `Subscription::wait` gave.
enum Step {
    /// The array the fresh sample was copied into.
    Fresh(Spare),
    Stale,
    Terminated,
    Interrupted,
}

/// The share of predictive waits (percent) whose timer may fire after the sample landed, for a
/// Python subscriber: 25, against dvrk-ipc's 10 for a Rust one. The interpreter's own
/// hand-off (a few µs) hides a later wake-up in one wait of four, and the shorter polling
/// window it allows brings a Python consumer nearer the 10% of a core issue 23 sets (15% for a
/// Rust one). Measured 2026-11-29, six alternating 4 s runs of the latency harness at one
/// subscriber (medians): 9.3% of a core against 11.3% at 10, the p50 hand-off 8.9 against
/// 7.7 µs and the p99 101 against 90 µs.
const PYTHON_PREDICTIVE_LATE_PERCENT: i64 = 25;

/// A subscriber to one topic of an arm (`dvrk_ipc::Subscription`), waiting with the chosen
/// strategy in compiled code with the GIL released. One thread only (`unsendable`): like every
/// iceoryx2 `ipc` port, it may not move between threads.
#[pyclass(unsendable, module = "dvrk_sidecar._native", name = "Subscription")]
struct NativeSubscription {
    inner: Option<Inner>,
    /// Keeps the node alive as long as its ports.
    _node: Rc<Node<Service>>,
    service_name: String,
    wait: WaitStrategy,
    size: usize,
    dtype: Py<PyAny>,
    frombuffer: Py<PyAny>,
    /// The array the next sample `wait` receives is copied into, made before the wait (see
    /// [`Spare`]); `None` until the first wait and after each fresh sample.
    spare: Option<Spare>,
    terminated: bool,
}

/// A new numpy array over a new, zeroed `bytearray` of the message's size, made before the
/// sample lands (see [`NativeSubscription::wait`]) so that the hand-off is a copy into it, not
/// the construction of the array (which costs more than the copy with caches cold after the
/// sleep, and with many subscribers delays every one queued behind). Each sample still gets an
/// array of its own: a spare is handed out once, and the next wait makes another.
struct Spare {
    /// Owns the buffer `dest` points into (the array holds it, too).
    _bytes: Py<PyByteArray>,
    array: Py<PyAny>,
    /// The bytearray's buffer of the message's size. Stays valid: the array's export of the
    /// buffer keeps the bytearray from being resized, and both live as long as the spare.
    dest: *mut u8,
}

impl Spare {
    fn new(
        py: Python<'_>,
        frombuffer: &Py<PyAny>,
        dtype: &Py<PyAny>,
        size: usize,
    ) -> PyResult<Self> {
        let bytes = PyByteArray::new_with(py, size, |_| Ok(()))?;
        let array = frombuffer.call1(py, (&bytes, dtype.bind(py)))?;
        let dest = bytes.data();
        Ok(Self {
            _bytes: bytes.unbind(),
            array,
            dest,
        })
    }

    /// Copies `bytes`, the message (of the size given to [`Spare::new`]), into the array; no
    /// GIL needed (nothing else can reach the buffer before the array is handed out).
    fn fill(&mut self, bytes: &[u8], size: usize) {
        debug_assert_eq!(bytes.len(), size);
        // SAFETY: `dest` is the spare bytearray's buffer of `size` bytes (its dtype's
        // itemsize, checked equal to the message's size at construction), valid and unaliased
        // (see the field); at most `size` bytes are written.
        unsafe { core::ptr::copy_nonoverlapping(bytes.as_ptr(), self.dest, size.min(bytes.len())) };
    }
}

impl NativeSubscription {
    fn inner(&mut self) -> PyResult<&mut Inner> {
        self.inner
            .as_mut()
            .ok_or_else(|| NativeError::new_err(format!("{} is closed", self.service_name)))
    }

    /// One numpy array of shape (1,) and the structured dtype over a copy of `bytes`.
    fn array<'py>(
        py: Python<'py>,
        frombuffer: &Py<PyAny>,
        dtype: &Py<PyAny>,
        bytes: &[u8],
    ) -> PyResult<Bound<'py, PyAny>> {
        frombuffer
            .call1(py, (PyByteArray::new(py, bytes), dtype.bind(py)))
            .map(|a| a.into_bound(py))
    }
}

#[pymethods]
impl NativeSubscription {
    /// Subscribes to `topic` (e.g. `"compensated/local/measured_cp"`) of the arm `prefix` on
    /// `node`. `wait`: `"event"`, `"spin"` or `"predictive"`; `dtype`: the numpy structured
    /// dtype of the topic's message (its itemsize must be the message's size); `period_ns`:
    /// the publisher's nominal period; `deadline_s`: how long one wait in compiled code lasts
    /// without a sample before it comes back to Python to check the timeout and signals
    /// (`None`: dvrk-ipc's default, 10 ms at 1500 Hz); `predictive_late_percent`: with
    /// `"predictive"`, the share of waits (1-50 %) whose timer may fire after the sample landed
    /// ([`PYTHON_PREDICTIVE_LATE_PERCENT`] by default, against dvrk-ipc's 10).
    #[new]
    // The Python constructor's keyword arguments, one per option.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (node, prefix, topic, dtype, wait = "event", period_ns = 666_667, deadline_s = None, predictive_late_percent = PYTHON_PREDICTIVE_LATE_PERCENT))]
    fn new(
        py: Python<'_>,
        node: &NativeNode,
        prefix: &str,
        topic: &str,
        dtype: Py<PyAny>,
        wait: &str,
        period_ns: u64,
        deadline_s: Option<f64>,
        predictive_late_percent: i64,
    ) -> PyResult<Self> {
        let names = ServiceNames::new(prefix).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let t = Topic::from_suffix(topic)
            .ok_or_else(|| PyValueError::new_err(format!("unknown topic {topic:?}")))?;
        let strategy: WaitStrategy = wait
            .parse()
            .map_err(|e: dvrk_ipc::UnknownWaitStrategy| PyValueError::new_err(e.to_string()))?;
        if period_ns == 0 {
            return Err(PyValueError::new_err("period_ns must be > 0"));
        }
        let late = u8::try_from(predictive_late_percent)
            .ok()
            .filter(|p| dvrk_ipc::PREDICTIVE_LATE_PERCENT_RANGE.contains(p))
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "predictive_late_percent {predictive_late_percent}: must be within {}..={}",
                    dvrk_ipc::PREDICTIVE_LATE_PERCENT_RANGE.start(),
                    dvrk_ipc::PREDICTIVE_LATE_PERCENT_RANGE.end()
                ))
            })?;
        let options = SubscribeOptions {
            period: core::time::Duration::from_nanos(period_ns),
            wait: strategy,
            deadline: deadline_s
                .map(|s| core::time::Duration::from_nanos(seconds_to_ns(s).max(1_000_000))),
            predictive_late_percent: late,
        };
        let n = &*node.node;
        let (inner, size) = if t.carries::<PoseV2>() {
            let s = Subscription::with_options(n, &names, t, options);
            (s.map(Inner::Pose), PoseV2::SIZE)
        } else if t.carries::<JointStateV2>() {
            let s = Subscription::with_options(n, &names, t, options);
            (s.map(Inner::Joint), JointStateV2::SIZE)
        } else if t.carries::<JawStateV1>() {
            let s = Subscription::with_options(n, &names, t, options);
            (s.map(Inner::Jaw), JawStateV1::SIZE)
        } else {
            let s = Subscription::with_options(n, &names, t, options);
            (s.map(Inner::Status), CompensationStatusV4::SIZE)
        };
        let inner = inner.map_err(native_err)?;
        let itemsize: usize = dtype.bind(py).getattr("itemsize")?.extract()?;
        if itemsize != size {
            return Err(PyValueError::new_err(format!(
                "dtype of {itemsize} bytes for {topic}, whose message has {size}"
            )));
        }
        let frombuffer = py.import("numpy")?.getattr("frombuffer")?.unbind();
        Ok(Self {
            service_name: format!("{prefix}/{topic}"),
            inner: Some(inner),
            _node: node.node.clone(),
            wait: strategy,
            size,
            dtype,
            frombuffer,
            spare: None,
            terminated: false,
        })
    }

    /// Waits up to `timeout` seconds for the next sample (the GIL released) and returns the
    /// newest, after draining every buffered one: a numpy array of shape (1,) and the topic's
    /// dtype. `None` after `timeout`. Python signal handlers (Ctrl-C) run at least every
    /// `deadline_s`; an exception they raise comes out of this call.
    #[pyo3(signature = (timeout = 0.5))]
    fn wait<'py>(&mut self, py: Python<'py>, timeout: f64) -> PyResult<Option<Bound<'py, PyAny>>> {
        let until = dvrk_ipc::monotonic_ns().saturating_add(seconds_to_ns(timeout));
        loop {
            // The predictive wait makes the spare when it is about to poll for a sample that is
            // due (`wait_prepared`), with the GIL taken back for it: after its timer, shortly
            // before the sample, not between the last sample and this wait, where with more
            // subscribers than cores it delays the ones queued behind. The event and spinning
            // waits have no such moment (they would prepare right away): they make it here,
            // GIL held, and spare a second taking of the GIL per wait, which in a program
            // whose other threads keep the GIL busy can cost a switch interval (5 ms). Made
            // after the sample lands when the wait had no moment to prepare in (a sample
            // already there).
            if self.wait != WaitStrategy::Predictive && self.spare.is_none() {
                self.spare = Some(Spare::new(py, &self.frombuffer, &self.dtype, self.size)?);
            }
            let size = self.size;
            let (frombuffer, dtype) = (&self.frombuffer, &self.dtype);
            let inner = self
                .inner
                .as_mut()
                .ok_or_else(|| NativeError::new_err(format!("{} is closed", self.service_name)))?;
            let state = OnThisThread(self.spare.take());
            let (step, spare) = each_type!(inner, s => {
                let s = OnThisThread(s);
                py.detach(move || {
                    let mut spare = state.into_inner();
                    let mut made = Ok(());
                    let make = |spare: &mut Option<Spare>, made: &mut PyResult<()>| {
                        if spare.is_none() && made.is_ok() {
                            match Python::attach(|py| Spare::new(py, frombuffer, dtype, size)) {
                                Ok(new) => *spare = Some(new),
                                Err(e) => *made = Err(e),
                            }
                        }
                    };
                    let update = s
                        .into_inner()
                        .wait_prepared(|_| {}, || make(&mut spare, &mut made));
                    let step = match update {
                        Err(e) => Err(native_err(e)),
                        Ok(Update::Fresh(v)) => {
                            make(&mut spare, &mut made);
                            made.and_then(|()| match spare.take() {
                                Some(mut full) => {
                                    full.fill(bytes_of(&v), size);
                                    Ok(Step::Fresh(full))
                                }
                                None => Err(native_err("no array to hand the sample over in")),
                            })
                        }
                        Ok(Update::Stale { .. }) => Ok(Step::Stale),
                        Ok(Update::Terminated) => Ok(Step::Terminated),
                        Ok(Update::Interrupted) => Ok(Step::Interrupted),
                    };
                    OnThisThread((step, spare))
                })
                .into_inner()
            });
            match step? {
                Step::Fresh(full) => {
                    self.terminated = false;
                    return Ok(Some(full.array.into_bound(py)));
                }
                Step::Terminated => self.terminated = true,
                Step::Stale | Step::Interrupted => {}
            }
            self.spare = spare;
            py.check_signals()?;
            if dvrk_ipc::monotonic_ns() >= until {
                return Ok(None);
            }
        }
    }

    /// The newest sample received since the last call, without waiting (drains the buffer;
    /// does not consume cycle events); `None` when nothing new arrived.
    fn take<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let frombuffer = &self.frombuffer;
        let dtype = &self.dtype;
        let inner = self
            .inner
            .as_mut()
            .ok_or_else(|| NativeError::new_err(format!("{} is closed", self.service_name)))?;
        each_type!(inner, s => match s.try_latest().map_err(native_err)? {
            Some(v) => Ok(Some(Self::array(py, frombuffer, dtype, bytes_of(&v))?)),
            None => Ok(None),
        })
    }

    /// The newest sample ever received (a new array each call), `None` before the first.
    fn latest<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let frombuffer = &self.frombuffer;
        let dtype = &self.dtype;
        let inner = self
            .inner
            .as_mut()
            .ok_or_else(|| NativeError::new_err(format!("{} is closed", self.service_name)))?;
        each_type!(inner, s => match s.latest() {
            Some(v) => Ok(Some(Self::array(py, frombuffer, dtype, bytes_of(v))?)),
            None => Ok(None),
        })
    }

    /// Publishers connected to the topic.
    fn publishers(&mut self) -> PyResult<usize> {
        Ok(each_type!(self.inner()?, s => s.number_of_publishers()))
    }

    /// Whether the last wait saw the publisher go away (stopped or died).
    #[getter]
    fn terminated(&self) -> bool {
        self.terminated
    }

    /// dvrk_ipc::SubscriptionStats as a dict.
    fn stats<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let st = each_type!(self.inner()?, s => s.stats());
        let d = PyDict::new(py);
        d.set_item("received_total", st.received_total)?;
        d.set_item("superseded_total", st.superseded_total)?;
        d.set_item("seq_gaps_total", st.seq_gaps_total)?;
        d.set_item("stale_total", st.stale_total)?;
        d.set_item("predicted_on_time_total", st.predicted_on_time_total)?;
        d.set_item("predicted_late_total", st.predicted_late_total)?;
        d.set_item("predicted_missed_total", st.predicted_missed_total)?;
        d.set_item("predicted_skipped_total", st.predicted_skipped_total)?;
        Ok(d)
    }

    /// The predictive model (period_ns, next_arrival_ns, guard_ns, spin_after_ns), `None`
    /// until learnt.
    fn prediction(&mut self) -> PyResult<Option<(u64, u64, u64, u64)>> {
        let p = each_type!(self.inner()?, s => s.prediction());
        Ok(p.map(|p| (p.period_ns, p.next_arrival_ns, p.guard_ns, p.spin_after_ns)))
    }

    /// `<prefix>/<topic>`.
    #[getter]
    fn service_name(&self) -> &str {
        &self.service_name
    }

    /// `"event"`, `"spin"` or `"predictive"`.
    #[getter]
    fn wait_strategy(&self) -> &'static str {
        self.wait.name()
    }

    /// The message's size in bytes.
    #[getter]
    fn size(&self) -> usize {
        self.size
    }

    /// Releases the subscriber and its listener.
    fn close(&mut self) {
        self.inner = None;
    }
}

/// The compiled half of `dvrk_sidecar`.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NativeNode>()?;
    m.add_class::<NativeArmServices>()?;
    m.add_class::<NativeSubscription>()?;
    m.add("NativeError", m.py().get_type::<NativeError>())?;
    m.add("WAIT_STRATEGIES", ("event", "spin", "predictive"))?;
    m.add("NOMINAL_PERIOD_NS", 666_667u64)?;
    Ok(())
}
