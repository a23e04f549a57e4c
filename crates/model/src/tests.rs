//! Checks of the network against plain candle and against finite differences.

use super::*;

fn random(n: usize, seed: u64, lo: f32, hi: f32) -> Vec<f32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

/// The same network written with candle's stock `conv2d` and `max_pool2d`
/// (channels-first), for comparing forward passes.
fn reference_forward(net: &QNet, obs: &Tensor) -> Tensor {
    let b = obs.dim(0).unwrap();
    let img = obs.narrow(1, 0, FRAMES * SIDE * SIDE).unwrap().reshape((b, FRAMES, SIDE, SIDE)).unwrap();
    let w1 = net.p(0).reshape((C1, K1, K1, FRAMES)).unwrap().permute((0, 3, 1, 2)).unwrap().contiguous().unwrap();
    let x = img.conv2d(&w1, 0, S1, 1, 1).unwrap().broadcast_add(&net.p(1).reshape((1, C1, 1, 1)).unwrap()).unwrap().relu().unwrap();
    let w2 = net.p(2).reshape((C2, K2, K2, C1)).unwrap().permute((0, 3, 1, 2)).unwrap().contiguous().unwrap();
    let x = x.conv2d(&w2, 0, 1, 1, 1).unwrap().broadcast_add(&net.p(3).reshape((1, C2, 1, 1)).unwrap()).unwrap().relu().unwrap();
    let x = x.max_pool2d(2).unwrap().permute((0, 2, 3, 1)).unwrap().reshape((b, FEAT)).unwrap();
    let v = obs.narrow(1, FRAMES * SIDE * SIDE, VEL).unwrap();
    let v = v.matmul(&net.p(4).t().unwrap()).unwrap().broadcast_add(net.p(5)).unwrap().relu().unwrap();
    let h = Tensor::cat(&[&x, &v], 1).unwrap();
    let h = h.matmul(&net.p(6).t().unwrap()).unwrap().broadcast_add(net.p(7)).unwrap().relu().unwrap();
    h.matmul(&net.p(8).t().unwrap()).unwrap().broadcast_add(net.p(9)).unwrap()
}

#[test]
fn forward_matches_stock_candle_convolutions() {
    let dev = Device::Cpu;
    for seed in [1, 2, 3] {
        let net = QNet::new(seed, &dev).unwrap();
        let obs = Tensor::from_vec(random(5 * OBS_LEN, seed + 10, 0.0, 1.0), (5, OBS_LEN), &dev).unwrap();
        let a = net.forward(&obs).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let b = reference_forward(&net, &obs).flatten_all().unwrap().to_vec1::<f32>().unwrap();
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-4, "{a:?} vs {b:?}");
        }
    }
}

/// Autograd gradients of the DQN loss against central finite differences, in
/// every parameter tensor (convolutions and pooling included).
#[test]
fn gradients_match_finite_differences() {
    let dev = Device::Cpu;
    let cfg = DqnConfig { lr: 1e-3, gamma: 0.9, target_update: 1000, huber_delta: 10.0 };
    let dqn = Dqn::new(cfg, 4, &dev).unwrap();
    // Push the target net away from the online one so the TD error is not zero.
    dqn.target.load_flat(&random(num_params(), 99, -0.1, 0.1)).unwrap();
    let n = 6;
    let mut data = random(n * TRANSITION_LEN, 5, 0.0, 1.0);
    for i in 0..n {
        data[i * TRANSITION_LEN + 2 * OBS_LEN] = (i % 2) as f32;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 1] = 3.0;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 2] = if i == 3 { 1.0 } else { 0.0 };
    }
    let batch = Tensor::from_vec(data, (n, TRANSITION_LEN), &dev).unwrap();
    let loss = dqn.loss(&batch).unwrap();
    let grads = loss.backward().unwrap();
    let flat = dqn.online.to_flat().unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut off = 0;
    let mut checked = 0;
    for (pi, (name, shape)) in PARAMS.iter().enumerate() {
        let len: usize = shape.iter().product();
        let g = grads.get(dqn.online.vars()[pi].as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        // The largest-gradient entry and a few random ones.
        let mut idx: Vec<usize> = (0..4).map(|_| rng.random_range(0..len)).collect();
        idx.push((0..len).max_by(|a, b| g[*a].abs().total_cmp(&g[*b].abs())).unwrap());
        for i in idx {
            let eps = 1e-2f32;
            let mut plus = flat.clone();
            plus[off + i] += eps;
            dqn.online.load_flat(&plus).unwrap();
            let lp = dqn.loss(&batch).unwrap().to_scalar::<f32>().unwrap();
            let mut minus = flat.clone();
            minus[off + i] -= eps;
            dqn.online.load_flat(&minus).unwrap();
            let lm = dqn.loss(&batch).unwrap().to_scalar::<f32>().unwrap();
            dqn.online.load_flat(&flat).unwrap();
            let fd = (lp - lm) / (2.0 * eps);
            let tol = 2e-3 + 0.05 * fd.abs().max(g[i].abs());
            assert!((fd - g[i]).abs() <= tol, "{name}[{i}]: autograd {} vs finite difference {fd}", g[i]);
            checked += 1;
        }
        off += len;
    }
    assert_eq!(checked, 50);
}

#[test]
fn flat_weights_and_checkpoints_round_trip() {
    let dev = Device::Cpu;
    let a = QNet::new(1, &dev).unwrap();
    let b = QNet::new(2, &dev).unwrap();
    assert_ne!(a.to_flat().unwrap(), b.to_flat().unwrap());
    b.load_flat(&a.to_flat().unwrap()).unwrap();
    assert_eq!(a.to_flat().unwrap(), b.to_flat().unwrap());
    assert_eq!(a.to_flat().unwrap().len(), num_params());

    let dir = std::env::temp_dir().join(format!("rotorhive-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("w.safetensors");
    a.save(&path).unwrap();
    let c = QNet::new(3, &dev).unwrap();
    c.load(&path).unwrap();
    assert_eq!(a.to_flat().unwrap(), c.to_flat().unwrap());

    // A truncated file and a foreign file are refused with the file's name.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = c.load(&path).unwrap_err().to_string();
    assert!(e.contains("w.safetensors") && e.contains("valid"), "{e}");
    let other = HashMap::from([("conv1.weight".to_string(), Tensor::zeros((3, 3), DType::F32, &dev).unwrap())]);
    candle_core::safetensors::save(&other, &path).unwrap();
    let e = c.load(&path).unwrap_err().to_string();
    assert!(e.contains("shape") || e.contains("missing"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn updates_reduce_the_loss_on_a_fixed_batch() {
    let dev = Device::Cpu;
    let mut dqn = Dqn::new(DqnConfig { lr: 1e-3, gamma: 0.0, target_update: 10_000, huber_delta: 1.0 }, 1, &dev).unwrap();
    let n = 32;
    let mut data = random(n * TRANSITION_LEN, 11, 0.0, 1.0);
    for i in 0..n {
        data[i * TRANSITION_LEN + 2 * OBS_LEN] = (i % 2) as f32;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 1] = if i % 2 == 0 { 3.0 } else { -1.0 };
    }
    let first = dqn.update(&data).unwrap();
    let mut last = first;
    for _ in 0..60 {
        last = dqn.update(&data).unwrap();
    }
    assert!(last < first * 0.2, "loss went from {first} to {last}");
    assert_eq!(dqn.updates(), 61);
}
