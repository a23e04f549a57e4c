//! The observation's and the transition's layout: the constants of the task,
//! [`Shapes`] (every length computed from one value) and the 16-bit packing of
//! transitions as they travel and as the replay keeps them.

use crate::label_mask;

/// Side of the paper's square depth image, in pixels (`[sim.camera]` sets
/// another: [`Shapes::depth`]).
pub const DEPTH_SIDE: usize = 32;
/// Pixels in one of the paper's depth images.
pub const DEPTH_PIXELS: usize = DEPTH_SIDE * DEPTH_SIDE;
/// The smallest side of a depth image the network reads (its convolutions
/// and pooling leave one cell of 12).
pub const MIN_DEPTH_SIDE: usize = 12;
/// The largest side of a depth image the network reads.
pub const MAX_DEPTH_SIDE: usize = 256;
/// Depth frames stacked in one observation of the paper's task (previous
/// and current); `sim.frames` sets another count ([`Shapes::frames`]).
pub const FRAMES: usize = 2;
/// The most depth frames an observation stacks (`sim.frames`).
pub const MAX_FRAMES: usize = 8;
/// The most action periods between two stacked frames (`sim.frame_stride`).
pub const MAX_FRAME_STRIDE: usize = 8;
/// Components of the body-frame linear velocity in an observation.
pub const VEL_DIM: usize = 3;
/// Floats of the goal in an observation of a task with a goal
/// (`[sim.goal]`): its bearing (rad, body frame), its distance and its
/// lateral offset (body frame), both in tens of metres.
pub const GOAL_DIM: usize = 3;
/// The most floats the camera's map (`[sim.map]`) may add to an
/// observation's scalars.
pub const MAX_MAP_FLOATS: usize = 1024;
/// Floats of one seen mover (`[sim.tracks]`) in an observation.
pub const TRACK_FLOATS: usize = 14;
/// The most floats the seen movers (`[sim.tracks]`) may add to an
/// observation's scalars.
pub const MAX_TRACK_FLOATS: usize = 32 * TRACK_FLOATS;
/// Floats after `s` and `s'` in a transition: the action taken, the
/// (n-step) reward, done (0 or 1), the teacher's label at `s` (the action
/// it holds the only right one there, or the set it holds best, see
/// [`label_mask`]; [`NO_EXPERT`] where it gave none)
/// and whether the teacher flew the step (1: a demonstration, 0: the
/// student's).
pub const TAIL: usize = 5;
/// The expert action of a transition or observation the teacher did not
/// label.
pub const NO_EXPERT: f32 = -1.0;
/// Number of discrete actions of the paper's task (lateral velocity
/// −0.25 m/s, +0.25 m/s); a task with the hold action has a third.
pub const NUM_ACTIONS: usize = 2;

/// The shapes of a run's observations and actions, taken from its config
/// (`Config::shapes` in the roles): every layout that depends on them
/// (observation batches, transitions as they travel and as the learner reads
/// them, the network's input and output) is computed here from one value,
/// so a sender and a receiver of one run never disagree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shapes {
    /// Depth frames stacked in one observation, oldest first (`stride`
    /// action periods apart; the last is the current view).
    pub frames: usize,
    /// Action periods between two stacked frames (1: consecutive views).
    /// No layout depends on it, but a network trained on one stride reads
    /// another's observations wrongly, so checkpoints say it too.
    pub stride: usize,
    /// Floats after the depth frames: the body-frame velocity, then (with a
    /// goal) the goal's [`GOAL_DIM`] floats, then the camera's map's
    /// [`Shapes::map`] floats, then the seen movers' [`Shapes::tracks`].
    pub scalars: usize,
    /// Discrete actions.
    pub actions: usize,
    /// Floats of the camera's map at the end of the scalars (0: no map).
    pub map: usize,
    /// Floats of the seen movers at the very end of the scalars, after the
    /// map (0: no tracks).
    pub tracks: usize,
    /// Rows and columns of one depth frame as the network reads it (the
    /// camera's image after its min-pool; `[32, 32]`, the paper's).
    pub depth: [usize; 2],
}

impl Shapes {
    /// The paper's task: velocity only, two actions.
    pub const PAPER: Shapes = Shapes {
        frames: FRAMES,
        stride: 1,
        scalars: VEL_DIM,
        actions: NUM_ACTIONS,
        map: 0,
        tracks: 0,
        depth: [DEPTH_SIDE, DEPTH_SIDE],
    };
    /// The most actions any task has.
    pub const MAX_ACTIONS: usize = NUM_ACTIONS + 1;

    /// The shapes of a task: `frames` consecutive depth frames, with or
    /// without a goal in the observation, with or without the hold action.
    pub const fn task(frames: usize, goal: bool, hold: bool) -> Self {
        Self {
            frames,
            stride: 1,
            scalars: VEL_DIM + if goal { GOAL_DIM } else { 0 },
            actions: NUM_ACTIONS + hold as usize,
            map: 0,
            tracks: 0,
            depth: [DEPTH_SIDE, DEPTH_SIDE],
        }
    }

    /// The same shapes with depth frames of `rows` x `cols` pixels.
    pub const fn with_depth(self, [rows, cols]: [usize; 2]) -> Self {
        Self { depth: [rows, cols], ..self }
    }

    /// Pixels in one depth frame.
    pub const fn depth_pixels(self) -> usize {
        self.depth[0] * self.depth[1]
    }

    /// The same shapes with `floats` of the camera's map after the other
    /// scalars (replacing any map they had).
    pub const fn with_map(self, floats: usize) -> Self {
        Self { scalars: self.scalars - self.map + floats, map: floats, ..self }
    }

    /// The same shapes with `floats` of the seen movers at the end of the
    /// scalars (replacing any they had).
    pub const fn with_tracks(self, floats: usize) -> Self {
        Self { scalars: self.scalars - self.tracks + floats, tracks: floats, ..self }
    }

    /// Floats of the memory at the end of the scalars: the map's, then the
    /// tracks'.
    pub const fn memory_floats(self) -> usize {
        self.map + self.tracks
    }

    /// Whether the observation holds a goal's [`GOAL_DIM`] floats (after
    /// the velocity, before the map).
    pub const fn goal(self) -> bool {
        self.scalars >= self.memory_floats() + VEL_DIM + GOAL_DIM
    }

    /// The same shapes with the stacked frames `stride` action periods apart.
    pub const fn with_stride(self, stride: usize) -> Self {
        Self { stride, ..self }
    }

    /// Depth values in one observation: the stacked frames.
    pub const fn obs_depth(self) -> usize {
        self.frames * self.depth_pixels()
    }

    /// Depth values in one packed transition: the frames of `s`, then
    /// those of `s'`.
    pub const fn packed_depth(self) -> usize {
        2 * self.obs_depth()
    }

    /// Floats in one observation: the stacked depth frames, then the scalars.
    pub const fn obs_len(self) -> usize {
        self.obs_depth() + self.scalars
    }

    /// Length of the `f32` payload of an observation batch of `agents`:
    /// their observations, rewards, done codes, the teacher's actions
    /// (where it flies the agent) and its labels.
    pub const fn obs_batch_len(self, agents: usize) -> usize {
        agents * (self.obs_len() + 4)
    }

    /// Floats in one transition as the learner uses it: `s (obs_len) | s'
    /// (obs_len) |` the [`TAIL`] floats (action, reward, done, expert, demo).
    pub const fn transition_len(self) -> usize {
        2 * self.obs_len() + TAIL
    }

    /// `f32` scalars in one packed transition: `s`'s scalars, `s'`'s, then
    /// the [`TAIL`] floats.
    pub const fn packed_scalars(self) -> usize {
        2 * self.scalars + TAIL
    }

    /// `u16` words in one packed transition, as transitions travel (actor →
    /// replay → learner) and as the replay stores them: depth as 16-bit
    /// fixed point (normalised depth × 65,535, rounded: 0.3 mm at a 20 m
    /// range, far under the renderers' 1 cm agreement), then each scalar's
    /// `f32` bits as two words (low, high). Half the bytes of
    /// [`Shapes::transition_len`] floats.
    pub const fn packed_len(self) -> usize {
        self.packed_depth() + 2 * self.packed_scalars()
    }

    /// The `i`-th scalar of a packed transition (`0..scalars` `s`'s,
    /// `scalars..2 × scalars` `s'`'s, then the [`TAIL`]): two `u16`
    /// words after the depth, low then high.
    #[inline]
    pub fn packed_scalar(self, p: &[u16], i: usize) -> f32 {
        word_f32(&p[self.packed_depth() + 2 * i..])
    }

    /// Packs one transition given as its parts (`s` and `s'` of
    /// [`Shapes::obs_len`] floats each, then the [`TAIL`]: action, reward,
    /// done, expert action, demonstration flag) into `out`
    /// ([`Shapes::packed_len`] words).
    pub fn pack(self, s: &[f32], next: &[f32], tail: [f32; TAIL], out: &mut [u16]) {
        let n = self.obs_len();
        assert!(
            s.len() == n && next.len() == n && out.len() == self.packed_len(),
            "pack: wrong lengths"
        );
        let fd = self.obs_depth();
        let (depth, scalars) = out.split_at_mut(self.packed_depth());
        for (o, v) in depth[..fd].iter_mut().zip(&s[..fd]) {
            *o = quantize_depth(*v);
        }
        for (o, v) in depth[fd..].iter_mut().zip(&next[..fd]) {
            *o = quantize_depth(*v);
        }
        let values = s[fd..].iter().chain(&next[fd..]).copied().chain(tail);
        for (o, v) in scalars.chunks_exact_mut(2).zip(values) {
            f32_words(v, o);
        }
    }

    /// Unpacks one transition ([`Shapes::packed_len`] words) into `out`
    /// ([`Shapes::transition_len`] floats, the learner's layout).
    pub fn unpack(self, p: &[u16], out: &mut [f32]) {
        assert!(
            p.len() == self.packed_len() && out.len() == self.transition_len(),
            "unpack: wrong lengths"
        );
        let (fd, k) = (self.obs_depth(), self.scalars);
        let (s, rest) = out.split_at_mut(self.obs_len());
        let (next, tail) = rest.split_at_mut(self.obs_len());
        for (o, q) in s[..fd].iter_mut().zip(&p[..fd]) {
            *o = dequantize_depth(*q);
        }
        for (o, q) in next[..fd].iter_mut().zip(&p[fd..2 * fd]) {
            *o = dequantize_depth(*q);
        }
        for j in 0..k {
            s[fd + j] = self.packed_scalar(p, j);
            next[fd + j] = self.packed_scalar(p, k + j);
        }
        for (j, o) in tail.iter_mut().enumerate() {
            *o = self.packed_scalar(p, 2 * k + j);
        }
    }

    /// True when a packed transition's scalars ([`Shapes::packed_scalars`]
    /// of them, see [`Shapes::packed_scalar`]) are not what an actor writes: an
    /// action that is not one of the run's, a done flag other than 0 or 1,
    /// a label that is none of [`label_mask`]'s,
    /// a demonstration flag other than 0 or 1, or a scalar that is not
    /// finite. A torn or forged write shows
    /// here (16-bit depth has no invalid value to look for).
    pub fn scalars_corrupt(self, scalars: &[f32]) -> bool {
        if scalars.len() != self.packed_scalars() {
            return true;
        }
        let tail = &scalars[2 * self.scalars..];
        let (action, done, expert, demo) = (tail[0], tail[2], tail[3], tail[4]);
        let one_of = |a: f32| a >= 0.0 && a < self.actions as f32 && a.fract() == 0.0;
        let flag = |f: f32| f == 0.0 || f == 1.0;
        !one_of(action)
            || !flag(done)
            || label_mask(expert, self.actions).is_none()
            || !flag(demo)
            || scalars.iter().any(|v| !v.is_finite())
    }

    /// Corrupt transitions (by [`Shapes::scalars_corrupt`]) in a batch of
    /// packed ones.
    pub fn corrupt_transitions(self, batch: &[u16]) -> u64 {
        let mut s = vec![0f32; self.packed_scalars()];
        batch
            .chunks_exact(self.packed_len())
            .filter(|t| {
                for (k, v) in s.iter_mut().enumerate() {
                    *v = self.packed_scalar(t, k);
                }
                self.scalars_corrupt(&s)
            })
            .count() as u64
    }

    /// Checks that the shapes are ones a task has (as a checkpoint's header
    /// claims them): 1 to [`MAX_FRAMES`] depth frames, the velocity with or
    /// without the goal, two actions or three.
    pub fn check(self) -> Result<Self, String> {
        if !(1..=MAX_FRAMES).contains(&self.frames) {
            return Err(format!("{} depth frames (1 to {MAX_FRAMES})", self.frames));
        }
        if !(1..=MAX_FRAME_STRIDE).contains(&self.stride) {
            return Err(format!(
                "a frame stride of {} action periods (1 to {MAX_FRAME_STRIDE})",
                self.stride
            ));
        }
        if let Some(side) =
            self.depth.iter().find(|s| !(MIN_DEPTH_SIDE..=MAX_DEPTH_SIDE).contains(s))
        {
            return Err(format!(
                "depth frames of {} x {} pixels (each side {MIN_DEPTH_SIDE} to {MAX_DEPTH_SIDE}, not {side})",
                self.depth[0], self.depth[1]
            ));
        }
        if self.map > MAX_MAP_FLOATS {
            return Err(format!("{} floats of the map (at most {MAX_MAP_FLOATS})", self.map));
        }
        if self.tracks > MAX_TRACK_FLOATS || !self.tracks.is_multiple_of(TRACK_FLOATS) {
            return Err(format!(
                "{} floats of the seen movers (a multiple of {TRACK_FLOATS}, at most \
                 {MAX_TRACK_FLOATS})",
                self.tracks
            ));
        }
        let task = self.scalars.checked_sub(self.memory_floats());
        if task != Some(VEL_DIM) && task != Some(VEL_DIM + GOAL_DIM) {
            return Err(format!(
                "{} observation scalars with {} of the map and {} of the tracks (a task has \
                 {VEL_DIM}, or {} with a goal, then the map's and the tracks')",
                self.scalars,
                self.map,
                self.tracks,
                VEL_DIM + GOAL_DIM
            ));
        }
        if !(NUM_ACTIONS..=Self::MAX_ACTIONS).contains(&self.actions) {
            return Err(format!(
                "{} actions (a task has {NUM_ACTIONS}, or {} with hold)",
                self.actions,
                Self::MAX_ACTIONS
            ));
        }
        Ok(self)
    }
}
#[inline]
pub(crate) fn f32_words(v: f32, out: &mut [u16]) {
    let b = v.to_bits();
    out[0] = b as u16;
    out[1] = (b >> 16) as u16;
}

/// The `f32` whose bits are `w[0]` (low) and `w[1]` (high): what
/// [`f32_words`] wrote.
#[inline]
pub(crate) fn word_f32(w: &[u16]) -> f32 {
    f32::from_bits(w[0] as u32 | (w[1] as u32) << 16)
}

/// A normalised depth in [0, 1] as 16-bit fixed point (clamped).
#[inline]
pub fn quantize_depth(d: f32) -> u16 {
    (d.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

/// The normalised depth of a 16-bit fixed-point value, in [0, 1].
#[inline]
pub fn dequantize_depth(q: u16) -> f32 {
    q as f32 / 65535.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode_corrupt;

    #[test]
    fn what_an_honest_actor_never_writes_is_corrupt() {
        let shapes = Shapes::PAPER;
        let obs = vec![0.5f32; shapes.obs_len()];
        let len = shapes.packed_len();
        let mut batch = vec![0u16; 11 * len];
        for (t, (a, r, d, e, demo)) in batch.chunks_exact_mut(len).zip([
            (1.0, 3.0, 0.0, NO_EXPERT, 0.0),
            (1.0, 3.0, 0.0, 0.0, 1.0),
            (0.0, 3.0, 1.0, 1.0, 0.0),
            (0.5, 3.0, 0.0, NO_EXPERT, 0.0),
            (0.0, f32::NAN, 1.0, NO_EXPERT, 0.0),
            (0.0, -100.0, 2.0, NO_EXPERT, 0.0),
            (0.0, -100.0, 1.0, NO_EXPERT, 0.0),
            (2.0, 3.0, 0.0, NO_EXPERT, 0.0),
            // A demonstration without a label (fine), an expert action
            // out of range, a flag neither 0 nor 1.
            (0.0, 3.0, 0.0, NO_EXPERT, 1.0),
            (0.0, 3.0, 0.0, 2.0, 0.0),
            (0.0, 3.0, 0.0, 0.0, 0.5),
        ]) {
            shapes.pack(&obs, &obs, [a, r, d, e, demo], t);
        }
        assert_eq!(shapes.corrupt_transitions(&batch[..3 * len]), 0);
        assert_eq!(shapes.corrupt_transitions(&batch), 6, "action 2 without hold");
        // With the hold action, action 2 is one of the task's.
        let hold = Shapes::task(FRAMES, false, true);
        assert_eq!(hold.packed_len(), len);
        assert_eq!(hold.corrupt_transitions(&batch), 4);
        assert!(!episode_corrupt(&[-100.0, 12.0, 1.0, 0.4]));
        assert!(!episode_corrupt(&[450.0, 150.0, 3.0, 0.0]));
        for bad in [
            [f32::NAN, 1.0, 1.0, 0.1],
            [1.0, 0.0, 1.0, 0.1],
            [1.0, 2.5, 1.0, 0.1],
            [1.0, 2.0, 0.0, 0.1],
            [1.0, 2.0, 4.0, 0.1],
            [1.0, 2.0, 1.0, -0.1],
        ] {
            assert!(episode_corrupt(&bad), "{bad:?}");
        }
        assert!(episode_corrupt(&[1.0, 2.0, 1.0]));
    }

    #[test]
    fn packed_transitions_round_trip_within_the_fixed_point_step() {
        // A task with four frames and a goal: six scalars per observation.
        let shapes = Shapes::task(4, true, true);
        let (obs_len, fd) = (shapes.obs_len(), shapes.obs_depth());
        assert_eq!(obs_len, 4 * 1024 + 6);
        assert_eq!(shapes.packed_len(), 2 * 4 * 1024 + 2 * (2 * 6 + TAIL));
        let s: Vec<f32> = (0..obs_len)
            .map(|i| if i < fd { (i as f32 * 0.618).fract() } else { -1.5 + i as f32 })
            .collect();
        let next: Vec<f32> = (0..obs_len)
            .map(|i| if i < fd { 1.0 - (i as f32 * 0.377).fract() } else { 0.25 * i as f32 })
            .collect();
        let mut p = vec![0u16; shapes.packed_len()];
        shapes.pack(&s, &next, [2.0, -100.0, 1.0, 1.0, 1.0], &mut p);
        let mut t = vec![0f32; shapes.transition_len()];
        shapes.unpack(&p, &mut t);
        for (a, b) in
            t[..fd].iter().zip(&s[..fd]).chain(t[obs_len..obs_len + fd].iter().zip(&next[..fd]))
        {
            assert!((a - b).abs() <= 0.5 / 65535.0 + 1e-7, "{a} vs {b}");
            assert!((0.0..=1.0).contains(a));
        }
        // Scalars travel bit for bit.
        assert_eq!(&t[fd..obs_len], &s[fd..]);
        assert_eq!(&t[obs_len + fd..2 * obs_len], &next[fd..]);
        assert_eq!(&t[2 * obs_len..], &[2.0, -100.0, 1.0, 1.0, 1.0]);
        assert_eq!(
            (dequantize_depth(quantize_depth(0.0)), dequantize_depth(quantize_depth(1.0))),
            (0.0, 1.0)
        );
        assert_eq!(quantize_depth(7.0), u16::MAX);
    }
}
