//! The network's widths ([`Layers`]): its two convolutions' channels and its
//! hidden layers', and the parameter list they give ([`params`]).
//!
//! The kernels stay the design's (conv 6×6 stride 2, conv 3×3, max-pool 2);
//! the maps' sizes follow the depth frame's ([`Geometry`]: a 6×6 pooled map
//! on the paper's 32×32). The
//! default, `[16, 32]` and `[64]`, is the network every earlier checkpoint
//! holds, and a checkpoint of it names no widths in its header (so its
//! bytes are those of earlier builds).

use crate::{K1, K2, ModelError, Result, S1, Shapes};

/// The most hidden layers a network may have.
pub const MAX_HIDDEN: usize = 3;
/// The widest a convolution or hidden layer may be.
pub const MAX_LAYER_WIDTH: usize = 1024;
/// Units of the velocity (and goal) branch.
pub(crate) const VEL_H: usize = 16;
/// Units of that branch when the scalars hold the camera's map or the seen
/// movers too: their tens of floats need more than the velocity's 16.
pub(crate) const MAP_VEL_H: usize = 64;

/// Units of the scalars' branch of a network for `shapes`.
pub(crate) const fn vel_units(shapes: Shapes) -> usize {
    if shapes.memory_floats() > 0 { MAP_VEL_H } else { VEL_H }
}

/// Names of the hidden layers' parameters: `fc1` first (the name every
/// checkpoint has), then `fc1b`, `fc1c`.
pub(crate) const HIDDEN_NAMES: [[&str; 2]; MAX_HIDDEN] =
    [["fc1.weight", "fc1.bias"], ["fc1b.weight", "fc1b.bias"], ["fc1c.weight", "fc1c.bias"]];

/// The sizes of the convolutions' maps on depth frames of `shapes.depth`:
/// conv1 6×6 stride 2, conv2 3×3, a 2×2 max-pool, each rounding down (as
/// candle's and ONNX's do): 32×32 → 14×14 → 12×12 → 6×6, the paper's; a
/// side of 12, the least (`MIN_DEPTH_SIDE`), leaves one pooled cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Geometry {
    /// The depth frame's rows and columns.
    pub(crate) h: usize,
    pub(crate) w: usize,
    /// conv1's output rows and columns.
    pub(crate) h1: usize,
    pub(crate) w1: usize,
    /// conv2's.
    pub(crate) h2: usize,
    pub(crate) w2: usize,
    /// The pooled map's.
    pub(crate) hp: usize,
    pub(crate) wp: usize,
}

impl Geometry {
    /// The geometry of `shapes`' depth frames (checked sizes:
    /// [`Shapes::check`]).
    pub(crate) const fn of(shapes: Shapes) -> Self {
        let [h, w] = shapes.depth;
        let (h1, w1) = ((h - K1) / S1 + 1, (w - K1) / S1 + 1);
        let (h2, w2) = (h1 - K2 + 1, w1 - K2 + 1);
        Self { h, w, h1, w1, h2, w2, hp: h2 / 2, wp: w2 / 2 }
    }

    /// Positions of conv1's map.
    pub(crate) const fn cells1(self) -> usize {
        self.h1 * self.w1
    }

    /// Positions of conv2's map.
    pub(crate) const fn cells2(self) -> usize {
        self.h2 * self.w2
    }

    /// Positions of the pooled map.
    pub(crate) const fn cells_pooled(self) -> usize {
        self.hp * self.wp
    }
}

/// A network's widths: the channels of its two convolutions and the units
/// of each hidden layer (one to [`MAX_HIDDEN`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Layers {
    conv: [usize; 2],
    hidden: [usize; MAX_HIDDEN],
    depth: usize,
}

impl Default for Layers {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Layers {
    /// The design's network: conv 16 and 32 channels, one hidden layer of 64.
    pub const DEFAULT: Layers = Layers { conv: [16, 32], hidden: [64, 0, 0], depth: 1 };

    /// Widths `conv` (two channel counts) and `hidden` (one to three
    /// widths), each 1 to [`MAX_LAYER_WIDTH`]; anything else is refused
    /// by name.
    pub fn new(conv: &[usize], hidden: &[usize]) -> Result<Self> {
        let bad = |what: String| Err(ModelError::Layers(what));
        if conv.len() != 2 {
            return bad(format!(
                "conv_channels has {} entries; this network has two convolutions",
                conv.len()
            ));
        }
        if hidden.is_empty() || hidden.len() > MAX_HIDDEN {
            return bad(format!("hidden has {} entries, not 1 to {MAX_HIDDEN}", hidden.len()));
        }
        if let Some(w) = conv.iter().chain(hidden).find(|w| !(1..=MAX_LAYER_WIDTH).contains(*w)) {
            return bad(format!("a width of {w}, not 1 to {MAX_LAYER_WIDTH}"));
        }
        let mut h = [0; MAX_HIDDEN];
        h[..hidden.len()].copy_from_slice(hidden);
        Ok(Self { conv: [conv[0], conv[1]], hidden: h, depth: hidden.len() })
    }

    /// The two convolutions' channels.
    pub fn conv(&self) -> [usize; 2] {
        self.conv
    }

    /// The hidden layers' widths, first to last.
    pub fn hidden(&self) -> &[usize] {
        &self.hidden[..self.depth]
    }

    /// Units of the last hidden layer: what the Q head (or the GRU) reads.
    pub fn out(&self) -> usize {
        self.hidden[self.depth - 1]
    }

    /// Floats of the pooled map of `shapes`' depth frames: its cells (6 ×
    /// 6 on 32 × 32) × the second convolution's channels.
    pub(crate) fn pooled(&self, shapes: Shapes) -> usize {
        Geometry::of(shapes).cells_pooled() * self.conv[1]
    }

    /// Floats entering the first hidden layer of a network for `shapes`:
    /// the pooled map, then the velocity branch.
    pub(crate) fn features(&self, shapes: Shapes) -> usize {
        self.pooled(shapes) + vel_units(shapes)
    }

    /// Parameters of the trunk (the convolutions, the velocity branch and
    /// the hidden layers), in canonical order.
    pub(crate) fn trunk_len(&self) -> usize {
        6 + 2 * self.depth
    }

    /// The widths as a header entry's value, `conv:16,32 hidden:64`.
    pub fn name(&self) -> String {
        let list = |v: &[usize]| v.iter().map(usize::to_string).collect::<Vec<_>>().join(",");
        format!("conv:{} hidden:{}", list(&self.conv), list(self.hidden()))
    }

    /// Widths from a header entry's value written by [`Layers::name`].
    pub fn parse(text: &str) -> Result<Self> {
        let bad = || ModelError::Layers(format!("{text:?} is not `conv:C1,C2 hidden:H1[,H2..]`"));
        let list = |s: Option<&str>, key: &str| -> Result<Vec<usize>> {
            let s = s.and_then(|s| s.strip_prefix(key)).ok_or_else(bad)?;
            s.split(',').map(|w| w.parse().map_err(|_| bad())).collect()
        };
        let mut parts = text.split(' ');
        let conv = list(parts.next(), "conv:")?;
        let hidden = list(parts.next(), "hidden:")?;
        if parts.next().is_some() {
            return Err(bad());
        }
        Self::new(&conv, &hidden)
    }
}

/// Parameter names and shapes of a network for `shapes` of widths
/// `layers`, in the canonical (flat) order: conv1, conv2, the velocity
/// branch (the observation's scalars enter `vel.weight`, the goal's floats
/// after the velocity), the hidden layers (`fc1`, then `fc1b`, `fc1c`),
/// then the Q head `fc2` (the actions leave it).
pub fn params(shapes: Shapes, layers: Layers) -> Vec<(&'static str, Vec<usize>)> {
    let mut p = trunk_params(shapes, layers);
    p.extend([
        ("fc2.weight", vec![shapes.actions, layers.out()]),
        ("fc2.bias", vec![shapes.actions]),
    ]);
    p
}

/// The trunk's part of [`params`]: everything before the Q head.
pub(crate) fn trunk_params(shapes: Shapes, layers: Layers) -> Vec<(&'static str, Vec<usize>)> {
    let [c1, c2] = layers.conv;
    let mut p = vec![
        ("conv1.weight", vec![c1, shapes.frames * K1 * K1]),
        ("conv1.bias", vec![c1]),
        ("conv2.weight", vec![c2, K2 * K2 * c1]),
        ("conv2.bias", vec![c2]),
        ("vel.weight", vec![vel_units(shapes), shapes.scalars]),
        ("vel.bias", vec![vel_units(shapes)]),
    ];
    let mut input = layers.features(shapes);
    for (&w, [wn, bn]) in layers.hidden().iter().zip(HIDDEN_NAMES) {
        p.extend([(wn, vec![w, input]), (bn, vec![w])]);
        input = w;
    }
    p
}

/// Number of floats in the flat weight vector of a network for `shapes`
/// of widths `layers`.
pub fn num_params(shapes: Shapes, layers: Layers) -> usize {
    params(shapes, layers).iter().map(|(_, s)| s.iter().product::<usize>()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn widths_are_checked_and_round_trip_through_their_name() {
        let l = Layers::new(&[32, 64], &[256, 128]).unwrap();
        assert_eq!(l.name(), "conv:32,64 hidden:256,128");
        assert_eq!(Layers::parse(&l.name()).unwrap(), l);
        assert_eq!(Layers::parse("conv:16,32 hidden:64").unwrap(), Layers::DEFAULT);
        assert_eq!(Layers::DEFAULT.out(), 64);
        for (conv, hidden, says) in [
            (&[16, 32, 64][..], &[64][..], "two convolutions"),
            (&[16, 32], &[], "not 1 to 3"),
            (&[16, 32], &[64, 64, 64, 64], "not 1 to 3"),
            (&[0, 32], &[64], "a width of 0"),
            (&[16, 32], &[4096], "a width of 4096"),
        ] {
            let e = Layers::new(conv, hidden).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
        for bad in ["conv:16 hidden:64", "hidden:64", "conv:16,32 hidden:x", "conv:16,32"] {
            assert!(Layers::parse(bad).is_err(), "{bad}");
        }
        // The design's network: 80,818 parameters for the paper's task.
        assert_eq!(num_params(Shapes::PAPER, Layers::DEFAULT), 80_818);
        // Other frames give other maps, rounding down: 64 × 48 → 30 × 22 →
        // 28 × 20 → 14 × 10; 13 → 4 → 2 → 1.
        let g = Geometry::of(Shapes::PAPER.with_depth([64, 48]));
        assert_eq!([g.h1, g.w1, g.h2, g.w2, g.hp, g.wp], [30, 22, 28, 20, 14, 10]);
        let g = Geometry::of(Shapes::PAPER.with_depth([13, 12]));
        assert_eq!([g.h1, g.w1, g.h2, g.w2, g.hp, g.wp], [4, 4, 2, 2, 1, 1]);
        assert_eq!(Layers::DEFAULT.pooled(Shapes::PAPER.with_depth([64, 48])), 14 * 10 * 32);
        let names: Vec<_> = params(Shapes::PAPER, l).into_iter().map(|(n, _)| n).collect();
        assert_eq!(
            names[6..],
            ["fc1.weight", "fc1.bias", "fc1b.weight", "fc1b.bias"]
                .iter()
                .chain(&["fc2.weight", "fc2.bias"])
                .copied()
                .collect::<Vec<_>>()[..]
        );
    }
}
