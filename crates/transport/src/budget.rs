//! Memory budgets: how many bytes of incoming frames a set of connections may
//! make this process hold at once.
//!
//! A reader that learns a frame's length reserves that many bytes from its
//! connection's [`MemoryBudget`] *before* allocating the frame
//! ([`ConnShared::admit`](crate::ConnShared::admit)); the [`Reservation`]
//! travels with the frame and is released when the application takes the
//! frame from its [`FrameReceiver`](crate::FrameReceiver) — or when the frame
//! is dropped with its connection. So the budget covers every byte a peer can
//! make the transport buffer: the frame being read and the complete frames
//! waiting to be read by the application. A reservation that does not fit is
//! refused at once ([`TransportError::OverBudget`]) and the connection is
//! closed: a peer over budget is never waited for, so no peer can hold
//! another's memory hostage by being slow.
//!
//! A listener hands one budget to every connection it accepts
//! ([`Listener::set_budget`](crate::Listener::set_budget)), so one budget
//! bounds a master's buffered bytes over all its peers.

use crate::TransportError;
use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A shared cap on bytes reserved by incoming frames (see the [module docs](self)).
pub struct MemoryBudget {
    limit: usize,
    in_use: AtomicUsize,
}

impl fmt::Debug for MemoryBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "MemoryBudget({} of {} bytes)", self.in_use(), self.limit)
    }
}

impl MemoryBudget {
    /// A budget of `limit_bytes`, none in use.
    pub fn new(limit_bytes: usize) -> Arc<Self> {
        Arc::new(Self { limit: limit_bytes, in_use: AtomicUsize::new(0) })
    }

    /// The cap, bytes.
    pub fn limit(&self) -> usize {
        self.limit
    }

    /// Bytes reserved now.
    pub fn in_use(&self) -> usize {
        self.in_use.load(Ordering::Acquire)
    }

    /// Reserves `len` bytes, or refuses with [`TransportError::OverBudget`]
    /// if they would take the total past the limit. Never waits.
    pub fn try_reserve(self: &Arc<Self>, len: usize) -> Result<Reservation, TransportError> {
        let limit = self.limit;
        match self.in_use.fetch_update(Ordering::AcqRel, Ordering::Acquire, |used| {
            used.checked_add(len).filter(|&total| total <= limit)
        }) {
            Ok(_) => Ok(Reservation { budget: Some(self.clone()), len }),
            Err(in_use) => Err(TransportError::OverBudget { len: len as u64, in_use, limit }),
        }
    }
}

/// Bytes reserved from a [`MemoryBudget`], given back when dropped.
pub struct Reservation {
    budget: Option<Arc<MemoryBudget>>,
    len: usize,
}

impl Reservation {
    /// A reservation from no budget (for connections that have none): holds
    /// nothing back.
    pub fn unbudgeted(len: usize) -> Self {
        Self { budget: None, len }
    }

    /// Bytes reserved.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no bytes are reserved.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl fmt::Debug for Reservation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "Reservation({} bytes{})",
            self.len,
            if self.budget.is_some() { "" } else { ", unbudgeted" }
        )
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if let Some(b) = &self.budget {
            b.in_use.fetch_sub(self.len, Ordering::AcqRel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_fit_the_limit_and_are_given_back_when_dropped() {
        let b = MemoryBudget::new(100);
        let r1 = b.try_reserve(60).unwrap();
        assert_eq!((b.in_use(), b.limit(), r1.len()), (60, 100, 60));
        match b.try_reserve(41) {
            Err(TransportError::OverBudget { len, in_use, limit }) => {
                assert_eq!((len, in_use, limit), (41, 60, 100))
            }
            other => panic!("expected OverBudget, got {other:?}"),
        }
        assert_eq!(b.in_use(), 60, "a refusal reserves nothing");
        let r2 = b.try_reserve(40).unwrap();
        assert_eq!(b.in_use(), 100);
        drop(r1);
        assert_eq!(b.in_use(), 40);
        drop(r2);
        assert_eq!(b.in_use(), 0);
        assert!(b.try_reserve(usize::MAX).is_err(), "no overflow");
        assert_eq!(b.in_use(), 0);
        let free = Reservation::unbudgeted(7);
        assert_eq!(free.len(), 7);
    }

    #[test]
    fn concurrent_reservations_never_exceed_the_limit() {
        let b = MemoryBudget::new(1000);
        let threads: Vec<_> = (0..4)
            .map(|_| {
                let b = b.clone();
                std::thread::spawn(move || {
                    for _ in 0..10_000 {
                        if let Ok(r) = b.try_reserve(300) {
                            assert!(b.in_use() <= 1000);
                            drop(r);
                        }
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(b.in_use(), 0);
    }
}
