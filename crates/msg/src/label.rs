//! The teacher's labels: none, one action, or a set of actions, as one
//! float of a transition's tail.

use crate::NO_EXPERT;

/// A label that allows several actions (`teacher.labels = "graded"` where
/// two of three keep the same room) is `LABEL_SET + mask`, the mask's bit
/// `a` set for each allowed action `a`; one action alone is its index.
pub const LABEL_SET: f32 = 8.0;

/// The actions a label allows, as bits (bit `a`: action `a`; 0 for
/// [`NO_EXPERT`]), for a task of `actions` actions; `None` where the value
/// is no label at all (not an index, not a set of at least one of the
/// task's actions, not finite).
pub fn label_mask(label: f32, actions: usize) -> Option<u8> {
    if label == NO_EXPERT {
        return Some(0);
    }
    if !(label.is_finite() && label >= 0.0 && label.fract() == 0.0) {
        return None;
    }
    let all = (1u32 << actions.min(8)) - 1;
    if label < actions as f32 {
        return Some(1 << label as u8);
    }
    let mask = label - LABEL_SET;
    (1.0..=all as f32).contains(&mask).then_some(mask as u8)
}

/// The label of the actions in `mask` (bit `a`: action `a`): [`NO_EXPERT`]
/// for none, the index for one, `LABEL_SET + mask` for several.
pub fn label_of_mask(mask: u8) -> f32 {
    match mask.count_ones() {
        0 => NO_EXPERT,
        1 => mask.trailing_zeros() as f32,
        _ => LABEL_SET + f32::from(mask),
    }
}

/// The one action a label names, where it names exactly one (DQfD's
/// margin loss needs one expert action; a set of several counts as none
/// there).
pub fn label_action(label: f32) -> Option<usize> {
    ((0.0..LABEL_SET).contains(&label) && label.fract() == 0.0).then_some(label as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_is_none_one_action_or_a_set_of_them() {
        assert_eq!(label_mask(NO_EXPERT, 3), Some(0));
        assert_eq!(label_mask(2.0, 3), Some(0b100));
        assert_eq!(label_mask(2.0, 2), None);
        assert_eq!(label_mask(label_of_mask(0b101), 3), Some(0b101));
        assert_eq!(label_mask(label_of_mask(0b101), 2), None, "action 2 of a two-action task");
        for bad in [0.5, -2.0, 8.0, f32::NAN, 16.0] {
            assert_eq!(label_mask(bad, 3), None, "{bad}");
        }
        assert_eq!(label_of_mask(0), NO_EXPERT);
        assert_eq!(label_of_mask(0b010), 1.0);
        assert_eq!((label_action(1.0), label_action(label_of_mask(0b011))), (Some(1), None));
    }
}
