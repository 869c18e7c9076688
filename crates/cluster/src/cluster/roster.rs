//! The slave list viewers are shown ([`Message::Slaves`]): every live slave
//! and the latest dead ones, with names and addresses cut to size.

use crate::protocol::{MAX_SLAVE_TEXT, MAX_SLAVES_LISTED, Message, SlaveEntry};
use std::collections::BTreeMap;

/// Dead slaves still listed to viewers (the most recent ones).
pub const DEAD_SLAVES_LISTED: usize = 16;

/// The slaves viewers are told about, by id.
#[derive(Debug, Default)]
pub(super) struct Roster {
    entries: BTreeMap<u64, SlaveEntry>,
}

/// At most [`MAX_SLAVE_TEXT`] bytes of `s` without control characters, cut
/// at a character boundary.
pub(super) fn cut(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars().filter(|c| !c.is_control()) {
        if out.len() + c.len_utf8() > MAX_SLAVE_TEXT {
            break;
        }
        out.push(c);
    }
    out
}

impl Roster {
    /// A slave joined.
    pub(super) fn join(&mut self, id: u64, name: &str, addr: &str, threads: u32) {
        self.entries.insert(id, SlaveEntry { id, name: cut(name), addr: cut(addr), threads, alive: true });
    }

    /// A slave died: it stays listed as dead, among the latest
    /// [`DEAD_SLAVES_LISTED`]. False if it was not listed.
    pub(super) fn death(&mut self, id: u64) -> bool {
        let Some(e) = self.entries.get_mut(&id) else { return false };
        e.alive = false;
        let dead: Vec<u64> = self.entries.values().filter(|e| !e.alive).map(|e| e.id).collect();
        for old in dead.iter().take(dead.len().saturating_sub(DEAD_SLAVES_LISTED)) {
            self.entries.remove(old);
        }
        true
    }

    /// The list as viewers get it: the live slaves, then the most recently
    /// dead (bounded by [`MAX_SLAVES_LISTED`]).
    pub(super) fn message(&self) -> Message {
        let live = self.entries.values().filter(|e| e.alive);
        let dead = self.entries.values().rev().filter(|e| !e.alive);
        let slaves = live.chain(dead).take(MAX_SLAVES_LISTED).cloned().collect();
        Message::Slaves { slaves }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_cut_and_the_dead_are_few_and_last() {
        let mut r = Roster::default();
        r.join(1, &"é".repeat(100), "a\u{7}ddr", 2);
        for id in 2..40 {
            r.join(id, "s", "x", 1);
            assert!(r.death(id));
        }
        assert!(!r.death(99));
        let Message::Slaves { slaves } = r.message() else { unreachable!() };
        assert_eq!(slaves.len(), 1 + DEAD_SLAVES_LISTED);
        assert!(slaves[0].alive && slaves[0].name.len() <= MAX_SLAVE_TEXT);
        assert_eq!(slaves[0].addr, "addr");
        assert_eq!(slaves[1].id, 39, "newest dead first");
    }
}
