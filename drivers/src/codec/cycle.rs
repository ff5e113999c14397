//! Output-cycle grouping for devices that send one sample as several packets (WitMotion
//! 0x50..0x5F packets, CAN messages), learning which packet type closes a cycle so a sample
//! is complete on its last packet instead of when the next cycle starts.
//!
//! Rule (tracked on packet kinds only, 0..64; the caller holds the sample's values):
//! - **Learning** (start, or after the pattern broke): a group ends when a kind arrives that
//!   the group already holds; the held group is emitted then (one packet late). If the
//!   repeated kind is the group's *first* kind, the group was one whole cycle: its kinds
//!   and its last kind (the *closing* kind) become the pattern.
//! - **Learned**: the group is emitted as soon as the closing kind arrives and the group
//!   holds exactly the pattern's kinds. A closing kind with other kinds held (a packet lost,
//!   or added), or a repeat before the closing kind (the closing packet lost, or the device
//!   reconfigured), drops the group, never emitting it as whole, and returns to learning.

/// What to do with the group held before the reported packet, and with the group after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Nothing: the group goes on.
    Keep,
    /// The group is whole: emit it.
    Emit,
    /// The group is incomplete: discard it.
    Drop,
}

/// The answer to one [`CycleGrouper::push`]: apply `before` to the held group, add the
/// packet's values to the (possibly fresh) group, then apply `after`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Step {
    pub before: Action,
    pub after: Action,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Pattern {
    members: u64,
    closing: u32,
}

/// The learning state machine described in the module doc.
#[derive(Debug, Default, Clone)]
pub struct CycleGrouper {
    held: u64,
    first: u32,
    last: u32,
    pattern: Option<Pattern>,
}

impl CycleGrouper {
    /// Reports one packet of `kind` (values ≥ 64 are folded into 63; callers use ≤ 16).
    pub fn push(&mut self, kind: u32) -> Step {
        let kind = kind.min(63);
        let bit = 1u64 << kind;
        let mut before = Action::Keep;
        if self.held & bit != 0 {
            before = match self.pattern {
                None => {
                    if kind == self.first {
                        self.pattern = Some(Pattern {
                            members: self.held,
                            closing: self.last,
                        });
                    }
                    Action::Emit
                }
                Some(_) => {
                    self.pattern = None;
                    Action::Drop
                }
            };
            self.held = 0;
        }
        if self.held == 0 {
            self.first = kind;
        }
        self.held |= bit;
        self.last = kind;
        let mut after = Action::Keep;
        if let Some(p) = self.pattern {
            if kind == p.closing {
                after = if self.held == p.members {
                    Action::Emit
                } else {
                    self.pattern = None;
                    Action::Drop
                };
                self.held = 0;
            }
        }
        Step { before, after }
    }

    /// Ends the input: true when the held group may be flushed as a sample. With a learned
    /// pattern a held group lacks its closing packet, so it is incomplete and not flushed;
    /// while learning, there is no way to tell, and it is flushed (the old rule).
    pub fn finish(&mut self) -> bool {
        let flush = self.held != 0 && self.pattern.is_none();
        self.held = 0;
        flush
    }

    /// Whether a pattern is currently learned.
    pub fn is_learned(&self) -> bool {
        self.pattern.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEEP: Step = Step {
        before: Action::Keep,
        after: Action::Keep,
    };

    #[test]
    fn learns_then_closes_on_the_last_kind() {
        let mut g = CycleGrouper::default();
        assert_eq!(g.push(0), KEEP);
        assert_eq!(g.push(1), KEEP);
        assert_eq!(g.push(2), KEEP);
        // First kind repeats: the held group was whole, the pattern is {0,1,2} closed by 2.
        assert_eq!(
            g.push(0),
            Step {
                before: Action::Emit,
                after: Action::Keep
            }
        );
        assert!(g.is_learned());
        assert_eq!(g.push(1), KEEP);
        assert_eq!(
            g.push(2),
            Step {
                before: Action::Keep,
                after: Action::Emit
            }
        );
        assert!(!g.finish(), "nothing held after a closed group");
    }

    #[test]
    fn single_kind_cycle_emits_twice_on_the_learning_packet() {
        let mut g = CycleGrouper::default();
        assert_eq!(g.push(2), KEEP);
        let both = Step {
            before: Action::Emit,
            after: Action::Emit,
        };
        assert_eq!(g.push(2), both);
        assert_eq!(
            g.push(2),
            Step {
                before: Action::Keep,
                after: Action::Emit
            }
        );
    }

    #[test]
    fn lost_closing_packet_drops_the_group_and_relearns() {
        let mut g = CycleGrouper::default();
        for k in [0, 1, 2, 0, 1, 2] {
            g.push(k);
        }
        g.push(0);
        g.push(1);
        // 2 lost: the repeat of 0 drops {0,1}.
        assert_eq!(g.push(0).before, Action::Drop);
        assert!(!g.is_learned());
        assert_eq!(g.push(1), KEEP);
        assert_eq!(g.push(2), KEEP);
        assert_eq!(g.push(0).before, Action::Emit);
        assert!(g.is_learned());
    }

    #[test]
    fn finish_flushes_only_while_learning() {
        let mut g = CycleGrouper::default();
        g.push(0);
        g.push(1);
        assert!(g.finish());
        for k in [0, 1, 0, 1, 0] {
            g.push(k);
        }
        assert!(
            !g.finish(),
            "learned: a group without its closing packet is partial"
        );
    }
}
