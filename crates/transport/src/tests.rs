use super::*;
use crate::channel::wait_slice;

#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[type_name("rotorhive::test::Hdr")]
#[repr(C)]
struct Hdr {
    seq: u64,
}

#[test]
fn a_wait_is_never_zero_whole_microseconds() {
    // iceoryx2 truncates to microseconds and blocks forever on zero.
    for ns in [0, 1, 400, 999, 1_000, 25_000_000] {
        let w = wait_slice(Duration::from_nanos(ns));
        assert!(w.as_micros() >= 1 && w <= Duration::from_millis(20), "{ns} ns -> {w:?}");
    }
}

#[test]
fn a_fill_that_fails_publishes_nothing() {
    let hub = Hub::<Local>::new("unit-fail", "unit").unwrap();
    let ch = Channel::weights(1);
    let mut tx = hub.sender::<f32, Hdr>(&ch, 8, Duration::from_millis(200)).unwrap();
    let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
    let failed = tx
        .try_send_with(8, |h, p| {
            h.seq = 1;
            p[0] = 1.0;
            Err("cannot write the weights")
        })
        .unwrap();
    assert_eq!(failed, Err("cannot write the weights"));
    assert_eq!(tx.sent(), 0);
    assert!(rx.try_recv().unwrap().is_none(), "a failed fill was published");
    tx.try_send_with(8, |h, p| {
        h.seq = 2;
        p.fill(2.0);
        Ok::<(), &str>(())
    })
    .unwrap()
    .unwrap();
    let m = rx.try_recv().unwrap().expect("the second message");
    assert_eq!((m.user_header().seq, m.payload()), (2, &[2.0f32; 8][..]));
}

#[test]
fn a_transition_sent_to_nobody_is_a_stall_and_one_sent_to_a_receiver_arrives() {
    let hub = Hub::<Local>::new("unit-nobody", "unit").unwrap();
    let ch = Channel::transitions(1);
    let mut tx = hub.sender::<f32, Hdr>(&ch, 4, Duration::from_millis(50)).unwrap();
    let t = std::time::Instant::now();
    let r = tx.send_with(4, |h, p| {
        h.seq = 1;
        p.fill(1.0);
    });
    assert!(matches!(r, Err(TransportError::Stalled { .. })), "{r:?}");
    assert!(t.elapsed() >= Duration::from_millis(50), "it waited for a receiver first");
    assert_eq!(tx.sent(), 0);
    let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
    tx.send_with(4, |h, p| {
        h.seq = 2;
        p.fill(2.0);
    })
    .unwrap();
    let m = rx.try_recv().unwrap().expect("the sample arrived");
    assert_eq!(m.user_header().seq, 2);
    // Other channels keep sending to nobody as before (telemetry, weights).
    let w = Channel::weights(1);
    let mut wtx = hub.sender::<f32, Hdr>(&w, 4, Duration::from_millis(50)).unwrap();
    wtx.send_with(4, |_, p| p.fill(0.0)).unwrap();
}

#[test]
fn local_channel_delivers_in_order_with_headers() {
    let hub = Hub::<Local>::new("unit", "unit").unwrap();
    let ch = Channel::obs(0, 1);
    let mut tx = hub.sender::<f32, Hdr>(&ch, 16, Duration::from_millis(200)).unwrap();
    let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
    for i in 0..2u64 {
        tx.send_with(16, |h, p| {
            h.seq = i;
            for (k, v) in p.iter_mut().enumerate() {
                *v = (i * 100 + k as u64) as f32;
            }
        })
        .unwrap();
    }
    // The buffer holds two: a third send meets back-pressure and stalls.
    let e = tx.send_with(16, |_, _| {}).unwrap_err();
    assert!(matches!(e, TransportError::Stalled { .. }), "{e}");
    for i in 0..2u64 {
        let m = rx.recv_timeout(Duration::from_millis(100)).unwrap().unwrap();
        assert_eq!(m.user_header().seq, i);
        assert_eq!(m.payload()[3], (i * 100 + 3) as f32);
    }
    assert!(rx.recv_timeout(Duration::from_millis(10)).unwrap().is_none());
}
