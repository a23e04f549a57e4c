//! The learner's weights to the actors and the evaluator: each
//! publication the next version, of the online network or (with
//! `learner.average_updates`) its running average.

use rotorhive_msg::WeightsHeader;
use rotorhive_transport::Service;

use crate::config::Config;
use crate::error::{Result, RoleError};

/// Polyak averaging of the published weights (`learner.average_updates`):
/// an exponential moving average of the online network's weights, folded
/// in at every publication, which the actors fly, the evaluator scores and
/// `final.safetensors` keeps. Training is unchanged. Not in the learner's
/// state: a restarted learner starts it again from the weights it restored.
pub struct Average {
    /// The share of each publication's weights: 1 − exp(−publish_every /
    /// average_updates).
    alpha: f32,
    /// The average (empty until the first finite weights).
    avg: Vec<f32>,
    /// The online weights of the last publication.
    fresh: Vec<f32>,
}

impl Average {
    /// The config's average, or none where `learner.average_updates` is 0.
    pub fn new(cfg: &Config) -> Option<Self> {
        let over = cfg.learner.average_updates;
        (over > 0.0).then(|| Self {
            alpha: (1.0 - (-(cfg.learner.publish_every as f64) / over).exp()) as f32,
            avg: Vec::new(),
            fresh: Vec::new(),
        })
    }

    /// Folds the `len` online weights that `write` puts in place into the
    /// average (the first finite ones start it; weights that are not all
    /// finite are left out of it).
    fn fold(&mut self, len: usize, write: impl FnOnce(&mut [f32]) -> Result<()>) -> Result<()> {
        self.fresh.resize(len, 0.0);
        write(&mut self.fresh)?;
        if !self.fresh.iter().all(|x| x.is_finite()) {
            return Ok(());
        }
        if self.avg.len() == len {
            let a = self.alpha;
            self.avg.iter_mut().zip(&self.fresh).for_each(|(m, w)| *m += a * (w - *m));
        } else {
            self.avg.clone_from(&self.fresh);
        }
        Ok(())
    }

    /// The weights to publish: the average, or the last online weights
    /// while there is none (weights that are not finite, which
    /// [`publish_flat`] refuses).
    pub fn weights(&self) -> &[f32] {
        if self.avg.is_empty() { &self.fresh } else { &self.avg }
    }
}

/// Publishes `len` weights that `write` puts in place, made after `updates`
/// updates, as the next version, or their running average where there is
/// one (the online network's, or its average).
pub fn publish_flat<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    (len, updates): (usize, u64),
    write: impl FnOnce(&mut [f32]) -> Result<()>,
    average: Option<&mut Average>,
    version: &mut u64,
) -> Result<()> {
    match average {
        Some(avg) => {
            avg.fold(len, write)?;
            let w = avg.weights();
            let write = |p: &mut [f32]| {
                p.copy_from_slice(w);
                Ok(())
            };
            send_flat(w_tx, (len, updates), write, version)
        }
        None => send_flat(w_tx, (len, updates), write, version),
    }
}

/// Sends `len` weights that `write` puts in place as the next version. A
/// failed write publishes nothing (no zero weights under a new version),
/// and neither do weights that are not all finite: the actors keep acting
/// with the last good ones, and the version is not spent.
fn send_flat<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    (len, updates): (usize, u64),
    write: impl FnOnce(&mut [f32]) -> Result<()>,
    version: &mut u64,
) -> Result<()> {
    let v = *version + 1;
    let sent = w_tx.try_send_with(len, |h, p| {
        *h = WeightsHeader { version: v, updates, len: len as u64 };
        write(p)?;
        match p.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(RoleError::Protocol(format!("parameter {i} is {}", p[i]))),
            None => Ok(()),
        }
    })?;
    match sent {
        Ok(()) => *version = v,
        Err(e) => tracing::warn!("learner: weights of update {updates} not published: {e:#}"),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    /// Weights `w` as a publication's `write`.
    fn put(w: &[f32]) -> impl FnOnce(&mut [f32]) -> Result<()> + '_ {
        move |p| {
            p.copy_from_slice(w);
            Ok(())
        }
    }

    fn average(over: f64) -> Option<Average> {
        let mut cfg = Config::default();
        cfg.learner.publish_every = 10;
        cfg.learner.average_updates = over;
        Average::new(&cfg)
    }

    #[test]
    fn the_average_starts_at_the_first_weights_and_follows_the_online_ones() {
        assert!(average(0.0).is_none(), "0 turns averaging off");
        let mut avg = average(100.0).expect("on");
        let alpha = 1.0 - (-0.1f64).exp() as f32;
        avg.fold(2, put(&[1.0, -2.0])).unwrap();
        assert_eq!(avg.weights(), &[1.0, -2.0]);
        avg.fold(2, put(&[3.0, -2.0])).unwrap();
        let w = avg.weights();
        assert!((w[0] - (1.0 + 2.0 * alpha)).abs() < 1e-6 && w[1] == -2.0, "{w:?}");
        // Many publications of the same weights: the average reaches them.
        for _ in 0..400 {
            avg.fold(2, put(&[3.0, 5.0])).unwrap();
        }
        assert!(avg.weights().iter().zip([3.0, 5.0]).all(|(a, b)| (a - b).abs() < 1e-4));
    }

    #[test]
    fn weights_that_are_not_finite_stay_out_of_the_average() {
        let mut avg = average(50.0).expect("on");
        avg.fold(2, put(&[f32::NAN, 1.0])).unwrap();
        assert!(avg.weights()[0].is_nan(), "no average yet: the bad weights, refused when sent");
        avg.fold(2, put(&[1.0, 1.0])).unwrap();
        avg.fold(2, put(&[f32::INFINITY, 1.0])).unwrap();
        assert_eq!(avg.weights(), &[1.0, 1.0]);
    }
}
