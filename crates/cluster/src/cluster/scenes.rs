//! The scenes a master holds: its default one and those clients uploaded,
//! each kept packed as slaves receive it ([`Packed`]: compressed, its
//! chunks' frames encoded once), by content hash, within a byte budget.
//!
//! A scene is in use while frames of it are open; those are never evicted,
//! nor is the default scene. When a new scene would overflow the budget the
//! least recently used idle scenes go first; if that is not enough the new
//! one is refused.

use crate::protocol::{self, SceneHash};
use crate::scene_stream::{self, Packed, StreamError};
use isin_tracer::SceneBundle;
use std::collections::BTreeMap;
use std::sync::Arc;

/// One held scene.
#[derive(Debug)]
struct Held {
    /// Its file name, for messages.
    name: String,
    /// The packed scene, shared by every transfer.
    packed: Arc<Packed>,
    /// Open frames that use it.
    uses: u32,
    /// A counter value of its last use (larger is more recent).
    used: u64,
}

/// Why a scene was not taken.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum StoreError {
    /// It cannot fit even with every idle scene evicted.
    #[error(
        "the scene is {bytes} bytes; the master holds at most {budget} bytes of scenes and {busy} are in use"
    )]
    Full {
        /// The scene's encoded size.
        bytes: usize,
        /// The budget.
        budget: usize,
        /// Bytes of scenes in use.
        busy: usize,
    },
    /// It could not be packed.
    #[error(transparent)]
    Encode(#[from] StreamError),
}

/// The master's scenes (see the [module docs](self)).
#[derive(Debug)]
pub(super) struct Scenes {
    held: BTreeMap<SceneHash, Held>,
    default: Option<SceneHash>,
    budget: usize,
    bytes: usize,
    clock: u64,
}

impl Scenes {
    /// No scenes, within `budget` bytes.
    pub(super) fn new(budget: usize) -> Self {
        Self { held: BTreeMap::new(), default: None, budget, bytes: 0, clock: 0 }
    }

    /// Takes `bundle` (named as served), returns its hash and what was
    /// evicted to make room. The default scene is taken whatever its size.
    pub(super) fn insert(
        &mut self,
        bundle: &SceneBundle,
        default: bool,
    ) -> Result<(SceneHash, Vec<SceneHash>), StoreError> {
        let hash = protocol::scene_hash(bundle);
        if self.held.contains_key(&hash) {
            self.touch(&hash);
            if default {
                self.default = Some(hash);
            }
            return Ok((hash, Vec::new()));
        }
        let packed = scene_stream::pack(bundle)?;
        let evicted = if default { Vec::new() } else { self.make_room(packed.wire_bytes() as usize)? };
        self.insert_packed(hash, bundle.name.clone(), Arc::new(packed));
        if default {
            self.default = Some(hash);
        }
        Ok((hash, evicted))
    }

    /// Takes a scene as stored on disk ([`Packed::to_stored`]): unpacked
    /// and its hash checked. Returns the hash.
    pub(super) fn insert_stored(&mut self, stored: &[u8]) -> Result<SceneHash, String> {
        let (packed, bundle) = Packed::from_stored(stored).map_err(|e| e.to_string())?;
        let hash = packed.header.hash;
        if !self.held.contains_key(&hash) {
            self.make_room(packed.wire_bytes() as usize).map_err(|e| e.to_string())?;
            self.insert_packed(hash, bundle.name, Arc::new(packed));
        }
        Ok(hash)
    }

    fn insert_packed(&mut self, hash: SceneHash, name: String, packed: Arc<Packed>) {
        self.clock += 1;
        self.bytes += packed.wire_bytes() as usize;
        self.held.insert(hash, Held { name, packed, uses: 0, used: self.clock });
    }

    /// Evicts idle scenes, least recently used first, until `bytes` more fit.
    fn make_room(&mut self, bytes: usize) -> Result<Vec<SceneHash>, StoreError> {
        let busy: usize = self
            .held
            .iter()
            .filter(|(h, s)| s.uses > 0 || Some(**h) == self.default)
            .map(|(_, s)| s.packed.wire_bytes() as usize)
            .sum();
        if busy + bytes > self.budget {
            return Err(StoreError::Full { bytes, budget: self.budget, busy });
        }
        let mut idle: Vec<(u64, SceneHash)> = self
            .held
            .iter()
            .filter(|(h, s)| s.uses == 0 && Some(**h) != self.default)
            .map(|(h, s)| (s.used, *h))
            .collect();
        idle.sort_unstable();
        let mut evicted = Vec::new();
        for (_, h) in idle {
            if self.bytes + bytes <= self.budget {
                break;
            }
            self.remove(&h);
            evicted.push(h);
        }
        Ok(evicted)
    }

    /// Forgets a scene (not the default one). False if it was not held or
    /// is the default.
    pub(super) fn remove(&mut self, hash: &SceneHash) -> bool {
        if Some(*hash) == self.default {
            return false;
        }
        match self.held.remove(hash) {
            Some(s) => {
                self.bytes -= s.packed.wire_bytes() as usize;
                true
            }
            None => false,
        }
    }

    fn touch(&mut self, hash: &SceneHash) {
        self.clock += 1;
        if let Some(s) = self.held.get_mut(hash) {
            s.used = self.clock;
        }
    }

    /// Whether the scene is held.
    pub(super) fn contains(&self, hash: &SceneHash) -> bool {
        self.held.contains_key(hash)
    }

    /// The default scene's hash.
    pub(super) fn default_hash(&self) -> Option<SceneHash> {
        self.default
    }

    /// The packed scene.
    pub(super) fn packed(&self, hash: &SceneHash) -> Option<Arc<Packed>> {
        self.held.get(hash).map(|s| s.packed.clone())
    }

    /// The scene's file name.
    pub(super) fn name(&self, hash: &SceneHash) -> Option<&str> {
        self.held.get(hash).map(|s| s.name.as_str())
    }

    /// A frame of the scene opened.
    pub(super) fn acquire(&mut self, hash: &SceneHash) {
        self.touch(hash);
        if let Some(s) = self.held.get_mut(hash) {
            s.uses += 1;
        }
    }

    /// A frame of the scene closed.
    pub(super) fn release(&mut self, hash: &SceneHash) {
        if let Some(s) = self.held.get_mut(hash) {
            s.uses = s.uses.saturating_sub(1);
        }
    }

    /// Scenes held.
    pub(super) fn len(&self) -> usize {
        self.held.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bundle of about `bytes` bytes packed (noise: zstd cannot shrink it).
    fn bundle(name: &str, bytes: usize) -> SceneBundle {
        let noise = crate::testing::Rng(0x9e37_79b9_7f4a_7c15u64 ^ name.len() as u64).bytes(bytes);
        let mut assets = BTreeMap::new();
        assets.insert("mesh.obj".to_string(), noise);
        SceneBundle { name: name.into(), source: format!("# {name}"), assets }
    }

    #[test]
    fn idle_scenes_are_evicted_least_recently_used_first_and_busy_ones_never() {
        let mut s = Scenes::new(3700);
        let (d, _) = s.insert(&bundle("default", 1000), true).unwrap();
        let (a, _) = s.insert(&bundle("a", 1000), false).unwrap();
        let (b, _) = s.insert(&bundle("b", 1000), false).unwrap();
        s.acquire(&a);
        // c needs room: b is idle (a is in use, the default is kept).
        let (c, evicted) = s.insert(&bundle("c", 1000), false).unwrap();
        assert_eq!(evicted, vec![b]);
        assert!(s.contains(&d) && s.contains(&a) && s.contains(&c) && !s.contains(&b));
        // With a, c in use and the default kept, nothing can make room.
        s.acquire(&c);
        let err = s.insert(&bundle("e", 1000), false).unwrap_err();
        assert!(matches!(err, StoreError::Full { .. }), "{err}");
        s.release(&a);
        let (_, evicted) = s.insert(&bundle("e", 1000), false).unwrap();
        assert_eq!(evicted, vec![a]);
        assert!(!s.remove(&d), "the default scene stays");
    }

    #[test]
    fn the_same_scene_twice_is_held_once_and_a_stored_one_reloads() {
        let mut s = Scenes::new(1 << 20);
        let (h1, _) = s.insert(&bundle("a", 100), false).unwrap();
        let (h2, _) = s.insert(&bundle("a", 100), false).unwrap();
        assert_eq!((h1, s.len()), (h2, 1));
        let stored = s.packed(&h1).unwrap().to_stored().unwrap();
        let mut t = Scenes::new(1 << 20);
        assert_eq!(t.insert_stored(&stored).unwrap(), h1);
        assert_eq!(t.name(&h1), Some("a"));
        // A corrupted copy is refused.
        let mut bad = stored;
        let n = bad.len();
        bad[n - 1] ^= 1;
        assert!(t.insert_stored(&bad).is_err());
    }
}
