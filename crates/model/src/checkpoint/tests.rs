//! Weights a checkpoint holds are checked before any network takes them:
//! a NaN, an infinity, integers or a tensor of another network are refused
//! by name, in the weights and in a learner's state.

use std::collections::HashMap;

use candle_core::{DType, Device, Tensor};

use crate::{Dqn, Layers, PolicyNet, QNet, Shapes, params};

fn dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("rotorhive-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn weights_that_cannot_compute_are_refused_by_name() {
    let dev = Device::Cpu;
    let d = dir("checked-weights");
    let path = d.join("w.safetensors");
    let a = QNet::new(3, &dev).unwrap();
    let fresh = || QNet::new(0, &dev).unwrap();
    let mut flat = a.to_flat().unwrap();
    // The first parameter is conv1.weight, the last fc2.bias.
    for (at, bad, name) in
        [(5, f32::NAN, "conv1.weight"), (flat.len() - 1, f32::INFINITY, "fc2.bias")]
    {
        let keep = flat[at];
        flat[at] = bad;
        a.load_flat(&flat).unwrap();
        a.save(&path).unwrap();
        flat[at] = keep;
        for e in [
            fresh().load(&path).unwrap_err().to_string(),
            PolicyNet::load(&path).err().unwrap().to_string(),
        ] {
            assert!(
                e.contains("w.safetensors")
                    && e.contains(&format!("tensor `{name}` holds 1 values of"))
                    && e.contains("not finite"),
                "{e}"
            );
        }
    }
    a.load_flat(&flat).unwrap();
    // Integers where floats belong, and a tensor the network lacks.
    let mut named = a.named();
    let shape = named["vel.bias"].dims().to_vec();
    named.insert("vel.bias".into(), Tensor::zeros(shape, DType::I64, &dev).unwrap());
    candle_core::safetensors::save(&named, &path).unwrap();
    let e = fresh().load(&path).unwrap_err().to_string();
    assert!(e.contains("tensor `vel.bias` holds I64, not floats"), "{e}");
    let mut named = a.named();
    named.insert("fc9.weight".into(), Tensor::zeros(3, DType::F32, &dev).unwrap());
    candle_core::safetensors::save(&named, &path).unwrap();
    let e = fresh().load(&path).unwrap_err().to_string();
    assert!(e.contains("tensor `fc9.weight` is not part of this network"), "{e}");
    // The sound weights still load, in half precision too.
    let half: HashMap<String, Tensor> =
        a.named().into_iter().map(|(k, t)| (k, t.to_dtype(DType::F16).unwrap())).collect();
    candle_core::safetensors::save(&half, &path).unwrap();
    fresh().load(&path).unwrap();
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_learner_state_with_a_broken_moment_is_refused_by_name() {
    let dev = Device::Cpu;
    let d = dir("checked-state");
    let path = d.join("learner-state.safetensors");
    let cfg = crate::tests::cfg(true);
    let dqn = Dqn::new(cfg, 1, &dev).unwrap();
    dqn.save_state(&path).unwrap();
    let mut back = Dqn::new(cfg, 2, &dev).unwrap();
    back.load_state(&path).unwrap();
    let mut state = candle_core::safetensors::load(&path, &dev).unwrap();
    let (last, shape) = params(Shapes::PAPER, Layers::DEFAULT).pop().unwrap();
    // The networks' tensors are named as the network names them.
    for (key, value, named) in [
        (format!("adam_v.{last}"), f32::NAN, format!("adam_v.{last}")),
        (format!("online.{last}"), f32::NEG_INFINITY, last.to_string()),
    ] {
        let good = state[&key].clone();
        let n: usize = shape.iter().product();
        let broken = Tensor::from_vec(vec![value; n], shape.as_slice(), &dev).unwrap();
        state.insert(key.clone(), broken);
        candle_core::safetensors::save(&state, &path).unwrap();
        let e = back.load_state(&path).unwrap_err().to_string();
        assert!(
            e.contains(&format!("tensor `{named}` holds {n} values of {n} that are not finite")),
            "{e}"
        );
        state.insert(key, good);
    }
    std::fs::remove_dir_all(&d).unwrap();
}
