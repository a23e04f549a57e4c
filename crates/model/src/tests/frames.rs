//! Networks of depth frames other than the paper's 32 × 32.

use super::*;

/// A network of another camera's frames: its header names them (one of
/// the paper's names none), the fused forward pass is stock candle's, a
/// network of 32 × 32 refuses it by name and `PolicyNet` loads it as it is.
#[test]
fn a_network_of_another_cameras_frames_round_trips_and_is_refused_by_name() {
    let dev = Device::Cpu;
    let dir = std::env::temp_dir().join(format!("rotorhive-depth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("w.safetensors");
    let shapes = Shapes::PAPER.with_depth([64, 48]);
    assert_eq!(shapes.check(), Ok(shapes));
    assert!(Shapes::PAPER.with_depth([11, 32]).check().unwrap_err().contains("11 x 32"));
    let net = QNet::with_shapes(shapes, 2, &dev).unwrap();
    let n = shapes.obs_len();
    let obs = Tensor::from_vec(random(4 * n, 9, 0.0, 1.0), (4, n), &dev).unwrap();
    let a = net.forward(&obs).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let b = generic(&net).forward(&obs).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    close(&a, &b, 1e-4, "q-values at 64 x 48");
    net.save(&path).unwrap();
    assert_eq!(checkpoint_shapes(&path).unwrap(), shapes);
    assert_eq!(checkpoint_entry(&path, "depth").unwrap().as_deref(), Some("64x48"));
    let back = PolicyNet::load(&path).unwrap();
    assert_eq!(back.shapes(), shapes);
    let e = QNet::new(0, &dev).unwrap().load(&path).unwrap_err().to_string();
    assert!(e.contains("depth 64x48 (this network: 32x32)"), "{e}");
    QNet::new(1, &dev).unwrap().save(&path).unwrap();
    assert_eq!(checkpoint_entry(&path, "depth").unwrap(), None);
    assert_eq!(checkpoint_shapes(&path).unwrap(), Shapes::PAPER);
    std::fs::remove_dir_all(&dir).unwrap();
}
