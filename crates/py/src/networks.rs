//! The network for Python: `PolicyNetwork`, Rust's one `PolicyNet` (the
//! feedforward Q-network, or with `memory` the recurrent one), of any
//! task's shapes and any widths, loaded from and saved as `hive train`
//! checkpoints, exported as ONNX. `rotorhive.QNetwork` and
//! `rotorhive.RecurrentQNetwork`, its names before, are kept in Python as
//! subclasses of it.

use std::path::PathBuf;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rotorhive_model::{Device, FRAMES, Layers, PolicyNet, Shapes, checkpoint_memory};

use crate::value_error;

fn model_error(e: rotorhive_model::ModelError) -> PyErr {
    value_error(e)
}

/// A run's policy network (`hive eval`'s), on the CPU: feedforward, or
/// with `memory` a GRU whose state each agent carries (the caller's, zeroed
/// where an episode starts; a feedforward network's state has no column).
#[pyclass(module = "rotorhive._rotorhive", name = "PolicyNetwork", subclass, unsendable)]
pub(crate) struct PolicyNetwork {
    net: PolicyNet,
}

impl PolicyNetwork {
    /// Checks a batch of flat observations (and, with `state`, its states)
    /// against the network: their rows, and the observations flattened.
    fn rows(
        &self,
        obs: &PyReadonlyArray2<'_, f32>,
        state: Option<&PyReadonlyArray2<'_, f32>>,
    ) -> PyResult<(usize, Vec<f32>)> {
        let (b, len, w) = (obs.shape()[0], self.net.shapes().obs_len(), self.net.state_width());
        if obs.shape()[1] != len || b == 0 || state.is_some_and(|s| s.shape() != [b, w]) {
            let (states, got) = match state {
                Some(s) => (
                    format!(" and states (B, {w})"),
                    format!("{:?} and {:?}", obs.shape(), s.shape()),
                ),
                None => (String::new(), format!("{:?}", obs.shape())),
            };
            return Err(value_error(format!(
                "observations must have shape (B, {len}) with B >= 1{states}, got {got}"
            )));
        }
        Ok((b, obs.as_array().iter().copied().collect()))
    }
}

#[pymethods]
impl PolicyNetwork {
    /// A freshly initialised network, deterministic for a seed: for the
    /// paper's task, or with the goal's floats in its observation (`goal`),
    /// the hold action (`hold`), another count of depth frames (`frames`)
    /// and frames further apart (`frame_stride` action periods); of the
    /// widths `conv_channels` (two) and `hidden` (one to three), as
    /// `learner.conv_channels` and `learner.hidden`; with `map` floats of
    /// the camera's map after the other scalars (`[sim.map]`), `tracks`
    /// floats of the seen movers after them (`[sim.tracks]`); with a GRU
    /// of `memory` units (`learner.memory = "gru:WIDTH"`), or none; on
    /// depth frames of `depth` (rows, columns: the camera's observed size).
    #[new]
    #[pyo3(signature = (seed=0, goal=false, hold=false, frames=FRAMES, frame_stride=1, conv_channels=vec![16, 32], hidden=vec![64], map=0, tracks=0, memory=None, depth=(32, 32)))]
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
        tracks: usize,
        memory: Option<usize>,
        depth: (usize, usize),
    ) -> PyResult<Self> {
        let shapes = Shapes::task(frames, goal, hold)
            .with_stride(frame_stride)
            .with_map(map)
            .with_tracks(tracks)
            .with_depth([depth.0, depth.1])
            .check()
            .map_err(value_error)?;
        let layers = Layers::new(&conv_channels, &hidden).map_err(model_error)?;
        let net =
            PolicyNet::new(shapes, layers, memory, seed, &Device::Cpu).map_err(model_error)?;
        Ok(Self { net })
    }

    /// Loads a checkpoint written by `hive train` (`checkpoints/*.safetensors`),
    /// of the shapes, widths and memory its header gives (a file that is
    /// not one, or whose weights are not finite, is refused by name).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(Self { net: PolicyNet::load(&path).map_err(model_error)? })
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

    /// The GRU's units (`None`: feedforward).
    #[getter]
    fn memory(&self) -> Option<usize> {
        self.net.memory()
    }

    /// Floats of one agent's state (the GRU's units; 0 feedforward).
    #[getter]
    fn width(&self) -> usize {
        self.net.state_width()
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

    /// Floats of the seen movers at the very end of an observation (0:
    /// none).
    #[getter]
    fn tracks(&self) -> usize {
        self.net.shapes().tracks
    }

    /// Rows and columns of the depth frames it reads.
    #[getter]
    fn depth(&self) -> (usize, usize) {
        let [rows, cols] = self.net.shapes().depth;
        (rows, cols)
    }

    /// Action periods between the depth frames it was trained on (1:
    /// consecutive views; the checkpoint's `frame_stride`).
    #[getter]
    fn frame_stride(&self) -> usize {
        self.net.shapes().stride
    }

    /// Saves the weights as a rotorhive checkpoint (its header names the
    /// shapes, widths and memory).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.net.save(&path, &[]).map_err(model_error)
    }

    /// Writes the network as an ONNX model (as `hive export`): inputs
    /// `depth` `(B, frames, rows, cols)` and `velocity` `(B, 3)` (with a goal
    /// `(B, 6)`: the velocity, then the goal's floats), then with the
    /// camera's map `map` `(B, floats)`, with the seen movers `tracks`
    /// `(B, floats)`, with memory `state` `(B, width)`;
    /// outputs `q` `(B, actions)`, with memory `next_state`.
    fn to_onnx(&self, path: PathBuf) -> PyResult<()> {
        self.net.to_onnx(&path, &[]).map_err(model_error)
    }

    /// Q-values `(B, actions)` of flat observations `(B, obs_len)`: the
    /// depth frames, oldest first, row-major, then the body-frame velocity
    /// (and, with a goal, the goal's floats; with the map, its floats; with
    /// the seen movers, theirs). A
    /// network with memory is stepped with `step`.
    fn q_values<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        if let Some(w) = self.net.memory() {
            return Err(value_error(format!(
                "a network with memory (gru:{w}) is stepped with its state: step(obs, state)"
            )));
        }
        let (b, flat) = self.rows(&obs, None)?;
        let q = self.net.q_values(&flat, &mut Vec::new()).map_err(model_error)?;
        let q = Array2::from_shape_vec((b, self.net.shapes().actions), q);
        Ok(q.expect("one Q-value per action and observation").into_pyarray(py))
    }

    /// Zero states `(batch, width)`: every agent at an episode's start.
    fn initial_state<'py>(&self, py: Python<'py>, batch: usize) -> Bound<'py, PyArray2<f32>> {
        Array2::<f32>::zeros((batch, self.net.state_width())).into_pyarray(py)
    }

    /// One step: Q-values `(B, actions)` of flat observations `(B,
    /// obs_len)` from states `(B, width)`, and the next states (a
    /// feedforward network's have no column).
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
        state: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<(Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>)> {
        let (b, flat) = self.rows(&obs, Some(&state))?;
        let w = self.net.state_width();
        let mut h: Vec<f32> = state.as_array().iter().copied().collect();
        let q = self.net.q_values(&flat, &mut h).map_err(model_error)?;
        let actions = self.net.shapes().actions;
        let q = Array2::from_shape_vec((b, actions), q).expect("one Q-value per action and row");
        let h = Array2::from_shape_vec((b, w), h).expect("one state per row");
        Ok((q.into_pyarray(py), h.into_pyarray(py)))
    }

    /// The weights in rotorhive's layout, by name (see `rotorhive.net` for
    /// PyTorch's).
    fn weights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let named = self.net.named();
        for (name, shape) in self.net.params() {
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

/// The GRU width a checkpoint's header names (`memory = "gru:WIDTH"`), or
/// None for a feedforward network's.
#[pyfunction]
pub(crate) fn checkpoint_width(path: PathBuf) -> PyResult<Option<usize>> {
    checkpoint_memory(&path).map_err(model_error)
}
