//! The networks for Python: `QNetwork` (feedforward) and
//! `RecurrentQNetwork` (with a GRU), of any task's shapes and any widths,
//! loaded from and saved as `hive train` checkpoints, exported as ONNX.

use std::path::PathBuf;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rotorhive_model::{
    Device, FRAMES, Layers, QNet, RecurrentQNet, Shapes, checkpoint_layers, checkpoint_memory,
    checkpoint_shapes, params,
};

use crate::value_error;

/// The shapes of a task with or without a goal and the hold action, of
/// `frames` depth frames `frame_stride` action periods apart (checked).
pub(crate) fn task_shapes(
    goal: bool,
    hold: bool,
    frames: usize,
    frame_stride: usize,
) -> PyResult<Shapes> {
    Shapes::task(frames, goal, hold).with_stride(frame_stride).check().map_err(value_error)
}

/// The learner's Q-network (`hive eval`'s network), on the CPU.
#[pyclass(module = "rotorhive._rotorhive", name = "QNetwork", unsendable)]
pub(crate) struct QNetwork {
    net: QNet,
}

fn model_error(e: rotorhive_model::ModelError) -> PyErr {
    value_error(e)
}

#[pymethods]
impl QNetwork {
    /// A freshly initialised network, deterministic for a seed: for the
    /// paper's task, or with the goal's floats in its observation (`goal`),
    /// the hold action (`hold`), another count of depth frames (`frames`)
    /// and frames further apart (`frame_stride` action periods); of the
    /// widths `conv_channels` (two) and `hidden` (one to three), as
    /// `learner.conv_channels` and `learner.hidden`; with `map` floats of
    /// the camera's map after the other scalars (`[sim.map]`).
    #[new]
    #[pyo3(signature = (seed=0, goal=false, hold=false, frames=FRAMES, frame_stride=1, conv_channels=vec![16, 32], hidden=vec![64], map=0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        seed: u64,
        goal: bool,
        hold: bool,
        frames: usize,
        frame_stride: usize,
        conv_channels: Vec<usize>,
        hidden: Vec<usize>,
        map: usize,
    ) -> PyResult<Self> {
        let shapes = Shapes::task(frames, goal, hold)
            .with_stride(frame_stride)
            .with_map(map)
            .check()
            .map_err(value_error)?;
        let layers = Layers::new(&conv_channels, &hidden).map_err(model_error)?;
        let net = QNet::with_layers(shapes, layers, seed, &Device::Cpu).map_err(model_error)?;
        Ok(Self { net })
    }

    /// Loads a checkpoint written by `hive train` (`checkpoints/*.safetensors`),
    /// of the shapes and widths its header gives.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let shapes = checkpoint_shapes(&path).map_err(model_error)?;
        let layers = checkpoint_layers(&path).map_err(model_error)?;
        let net = QNet::with_layers(shapes, layers, 0, &Device::Cpu).map_err(model_error)?;
        net.load(&path).map_err(model_error)?;
        Ok(Self { net })
    }

    /// The two convolutions' channels.
    #[getter]
    fn conv_channels(&self) -> Vec<usize> {
        self.net.layers().conv().to_vec()
    }

    /// The hidden layers' widths.
    #[getter]
    fn hidden(&self) -> Vec<usize> {
        self.net.layers().hidden().to_vec()
    }

    /// Floats of one flat observation (2051, or 2054 with a goal).
    #[getter]
    fn obs_len(&self) -> usize {
        self.net.shapes().obs_len()
    }

    /// Number of actions (2, or 3 with hold).
    #[getter]
    fn actions(&self) -> usize {
        self.net.shapes().actions
    }

    /// Floats of the camera's map at the end of an observation (0: none).
    #[getter]
    fn map(&self) -> usize {
        self.net.shapes().map
    }

    /// Action periods between the depth frames it was trained on (1:
    /// consecutive views; the checkpoint's `frame_stride`).
    #[getter]
    fn frame_stride(&self) -> usize {
        self.net.shapes().stride
    }

    /// Saves the weights as a rotorhive checkpoint.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.net.save(&path).map_err(model_error)
    }

    /// Writes the network as an ONNX model: inputs `depth` `(B, 2, 32, 32)`
    /// and `velocity` `(B, 3)` (with a goal `(B, 6)`: the velocity, then the
    /// goal's floats), then with the camera's map `map` `(B, floats)`,
    /// output `q` `(B, actions)` (as `hive export`).
    fn to_onnx(&self, path: PathBuf) -> PyResult<()> {
        self.net.to_onnx(&path, &[]).map_err(model_error)
    }

    /// Q-values `(B, actions)` of flat observations `(B, obs_len)`: the
    /// previous and the current depth frame, row-major, then the body-frame
    /// velocity (and, with a goal, the goal's floats).
    fn q_values<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let b = obs.shape()[0];
        let (len, actions) = (self.net.shapes().obs_len(), self.net.shapes().actions);
        if obs.shape()[1] != len || b == 0 {
            return Err(value_error(format!(
                "observations must have shape (B, {len}) with B >= 1, got {:?}",
                obs.shape()
            )));
        }
        let flat: Vec<f32> = obs.as_array().iter().copied().collect();
        let q = self.net.q_values(&flat).map_err(model_error)?;
        Ok(Array2::from_shape_vec((b, actions), q)
            .expect("one Q-value per action and observation")
            .into_pyarray(py))
    }

    /// The weights in rotorhive's layout, by name (see `rotorhive.net` for
    /// PyTorch's).
    fn weights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let named = self.net.named();
        for (name, shape) in params(self.net.shapes(), self.net.layers()) {
            let data: Vec<f32> = named[name]
                .flatten_all()
                .and_then(|t| t.to_vec1())
                .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
            let a =
                numpy::ndarray::ArrayD::from_shape_vec(shape, data).expect("the parameter's shape");
            d.set_item(name, a.into_pyarray(py))?;
        }
        Ok(d)
    }
}

/// A recurrent Q-network (the trunk, a GRU of `width` units, the Q head on
/// its state), on the CPU: stepped with each agent's state, which the
/// caller carries and zeroes where an episode starts.
#[pyclass(module = "rotorhive._rotorhive", name = "RecurrentQNetwork", unsendable)]
pub(crate) struct RecurrentQNetwork {
    net: RecurrentQNet,
}

#[pymethods]
impl RecurrentQNetwork {
    /// A freshly initialised network, deterministic for a seed, with a GRU
    /// of `width` units (the other arguments as `QNetwork`'s).
    #[new]
    #[pyo3(signature = (width=64, seed=0, goal=false, hold=false, frames=FRAMES, frame_stride=1, conv_channels=vec![16, 32], hidden=vec![64]))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        width: usize,
        seed: u64,
        goal: bool,
        hold: bool,
        frames: usize,
        frame_stride: usize,
        conv_channels: Vec<usize>,
        hidden: Vec<usize>,
    ) -> PyResult<Self> {
        let shapes = task_shapes(goal, hold, frames, frame_stride)?;
        let layers = Layers::new(&conv_channels, &hidden).map_err(model_error)?;
        let net = RecurrentQNet::with_layers(shapes, layers, width, seed, &Device::Cpu)
            .map_err(model_error)?;
        Ok(Self { net })
    }

    /// Loads a checkpoint whose header names a memory (`gru:WIDTH`), of the
    /// shapes and width it gives; a feedforward checkpoint is refused.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let shapes = checkpoint_shapes(&path).map_err(model_error)?;
        let Some(width) = checkpoint_memory(&path).map_err(model_error)? else {
            return Err(value_error(format!(
                "checkpoint {}: a feedforward network's (memory none): load it with QNetwork.load",
                path.display()
            )));
        };
        let layers = checkpoint_layers(&path).map_err(model_error)?;
        let net = RecurrentQNet::with_layers(shapes, layers, width, 0, &Device::Cpu)
            .map_err(model_error)?;
        net.load(&path).map_err(model_error)?;
        Ok(Self { net })
    }

    /// Floats of one agent's state: the GRU's units.
    #[getter]
    fn width(&self) -> usize {
        self.net.width()
    }

    /// Floats of one flat observation.
    #[getter]
    fn obs_len(&self) -> usize {
        self.net.shapes().obs_len()
    }

    /// Number of actions.
    #[getter]
    fn actions(&self) -> usize {
        self.net.shapes().actions
    }

    /// Zero states `(batch, width)`: every agent at an episode's start.
    fn initial_state<'py>(&self, py: Python<'py>, batch: usize) -> Bound<'py, PyArray2<f32>> {
        Array2::<f32>::zeros((batch, self.net.width())).into_pyarray(py)
    }

    /// Saves the weights as a rotorhive checkpoint (its header names the
    /// memory).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.net.save(&path, &[]).map_err(model_error)
    }

    /// Writes the network as an ONNX model of one step: inputs `depth`,
    /// `velocity` and `state` `(B, width)`, outputs `q` and `next_state`.
    fn to_onnx(&self, path: PathBuf) -> PyResult<()> {
        self.net.to_onnx(&path, &[]).map_err(model_error)
    }

    /// One step: Q-values `(B, actions)` of flat observations `(B,
    /// obs_len)` from states `(B, width)`, and the next states.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
        state: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<(Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>)> {
        let (b, w) = (obs.shape()[0], self.net.width());
        let (len, actions) = (self.net.shapes().obs_len(), self.net.shapes().actions);
        if obs.shape()[1] != len || b == 0 || state.shape() != [b, w] {
            return Err(value_error(format!(
                "observations must have shape (B, {len}) with B >= 1 and states (B, {w}), got {:?} and {:?}",
                obs.shape(),
                state.shape()
            )));
        }
        let flat: Vec<f32> = obs.as_array().iter().copied().collect();
        let mut h: Vec<f32> = state.as_array().iter().copied().collect();
        let q = self.net.step(&flat, &mut h).map_err(model_error)?;
        let q = Array2::from_shape_vec((b, actions), q).expect("one Q-value per action and row");
        let h = Array2::from_shape_vec((b, w), h).expect("one state per row");
        Ok((q.into_pyarray(py), h.into_pyarray(py)))
    }
}

/// The GRU width a checkpoint's header names (`memory = "gru:WIDTH"`), or
/// None for a feedforward network's.
#[pyfunction]
pub(crate) fn checkpoint_width(path: PathBuf) -> PyResult<Option<usize>> {
    checkpoint_memory(&path).map_err(model_error)
}
