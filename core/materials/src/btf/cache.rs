//! A bounded cache of a `.btf`'s texel blocks, read on demand from disk: how a
//! `BtfTable` shades a BTF whose values exceed its memory bound. Renderers look texels
//! up from every rayon worker at once, so the cache is split into shards (a block's
//! shard is its number modulo the shard count, so neighbouring blocks, which
//! neighbouring pixels want, land on different locks), each a small mutex-guarded clock
//! (second-chance) ring: a hit is one lock, one array index and a reference-count
//! increment; a miss reads the block outside the lock (positioned reads, no shared
//! cursor) and inserts it, evicting the first block whose reference bit is clear.
//! Blocks are handed out as `Arc`s, so an eviction never frees values a worker is still
//! reading. Values are held in the table's precision (f16 or f32), exactly as the
//! in-memory table holds them.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use half::f16;

use super::table::Storage;
use super::texels::TexelSource;

/// Block size aimed at: large enough that a miss is one efficient read, small enough
/// that a tight bound still holds many blocks (a Bonn 81 x 81 texel is 39 KB as f16).
pub const BLOCK_BYTES: u64 = 256 << 10;
/// Most shards: beyond the worker count, more shards only cost memory.
const MAX_SHARDS: usize = 64;
/// Blocks each worker may hold beyond the resident set: one it reads (with its f32
/// read buffer, up to two blocks' worth for f16 values) and one evicted under it.
const TRANSIENT_BLOCKS_PER_THREAD: u64 = 4;
/// Resident blocks a tight bound is still split into, when texels are small enough.
const MIN_RESIDENT: u64 = 4;
/// An empty index entry.
const ABSENT: u32 = u32::MAX;

/// One block's values, in the table's precision.
#[derive(Debug)]
pub enum Block {
    F16(Box<[f16]>),
    F32(Box<[f32]>),
}

/// How a cache is laid out: texels per block, resident blocks, shards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheShape {
    pub texels_per_block: usize,
    pub shards: usize,
    pub blocks_per_shard: usize,
}

impl CacheShape {
    /// The shape that keeps resident and in-flight blocks within `max_bytes` for
    /// `threads` workers, blocks of at most about `block_bytes` (at least one texel),
    /// or why no cache fits: the bound must hold one block besides the workers'.
    pub fn fit(
        texel_bytes: u64,
        texels: usize,
        max_bytes: u64,
        block_bytes: u64,
        threads: usize,
    ) -> Result<Self, String> {
        // Under a tight bound, smaller blocks, so that a few stay resident besides
        // the workers' (down to one texel).
        let target = block_bytes
            .min(max_bytes / (TRANSIENT_BLOCKS_PER_THREAD * threads.max(1) as u64 + MIN_RESIDENT));
        let texels_per_block = (target / texel_bytes.max(1)).clamp(1, texels as u64) as usize;
        let block = texels_per_block as u64 * texel_bytes;
        let transient = TRANSIENT_BLOCKS_PER_THREAD * threads.max(1) as u64 * block;
        let resident = max_bytes.saturating_sub(transient) / block;
        let total_blocks = texels.div_ceil(texels_per_block) as u64;
        if resident == 0 {
            return Err(format!(
                "a bound of {max_bytes} bytes holds no block of {block} bytes besides {transient} bytes in flight for {threads} threads: at least {} bytes are needed",
                transient + block
            ));
        }
        let resident = resident.min(total_blocks);
        let shards = (resident as usize).min(MAX_SHARDS);
        Ok(Self {
            texels_per_block,
            shards,
            blocks_per_shard: resident as usize / shards,
        })
    }

    /// Bytes the cache may hold at once, resident and in flight.
    pub fn bytes(&self, texel_bytes: u64, threads: usize) -> u64 {
        let block = self.texels_per_block as u64 * texel_bytes;
        (self.shards * self.blocks_per_shard) as u64 * block
            + TRANSIENT_BLOCKS_PER_THREAD * threads.max(1) as u64 * block
    }
}

struct Slot {
    /// The block's number within its shard.
    local: usize,
    values: Arc<Block>,
    /// The clock's second chance: set on every hit, cleared as the hand passes.
    used: bool,
}

/// One shard: a ring of resident blocks and, for each of the shard's block numbers,
/// the slot holding it (a dense array: block counts are small next to value counts).
struct Shard {
    slots: Vec<Slot>,
    index: Vec<u32>,
    hand: usize,
}

impl Shard {
    fn get(&mut self, local: usize) -> Option<Arc<Block>> {
        let slot = *self.index.get(local)?;
        if slot == ABSENT {
            return None;
        }
        let s = &mut self.slots[slot as usize];
        s.used = true;
        Some(Arc::clone(&s.values))
    }

    /// Inserts `values` as the shard's block `local`, evicting by clock once the
    /// shard holds `capacity` blocks.
    fn insert(&mut self, local: usize, values: Arc<Block>, capacity: usize) {
        let fresh = Slot {
            local,
            values,
            used: true,
        };
        if self.slots.len() < capacity {
            self.index[local] = self.slots.len() as u32;
            self.slots.push(fresh);
            return;
        }
        loop {
            let s = &mut self.slots[self.hand];
            if s.used {
                s.used = false;
                self.hand = (self.hand + 1) % self.slots.len();
                continue;
            }
            break;
        }
        let hand = self.hand;
        let old = std::mem::replace(&mut self.slots[hand], fresh);
        self.index[old.local] = ABSENT;
        self.index[local] = hand as u32;
        self.hand = (hand + 1) % self.slots.len();
    }
}

/// Where a cache reads its blocks: a `.btf` on disk (`on_disk::OnDiskBtf`), or
/// values computed on demand (`meso report fit`'s pack tabulated at a BTF's pairs).
pub type BlockSource = Box<dyn TexelSource + Send>;

/// A bounded, thread-safe cache of one BTF's texel blocks (see the module comment).
pub struct BlockCache {
    source: BlockSource,
    storage: Storage,
    shape: CacheShape,
    threads: usize,
    values_per_texel: usize,
    shards: Box<[Mutex<Shard>]>,
    /// Blocks read from disk, for tests and reports (misses, re-reads after eviction).
    reads: AtomicU64,
    /// The first read that failed after opening (the file changed under the render):
    /// its texels shade as 0 and whoever rendered reports it (`BtfTable::read_error`).
    error: OnceLock<String>,
}

impl std::fmt::Debug for BlockCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCache")
            .field("source", &self.source.name())
            .field("storage", &self.storage)
            .field("shape", &self.shape)
            .finish_non_exhaustive()
    }
}

impl BlockCache {
    /// A cache of `source`'s values in `storage` precision laid out as `shape` (for
    /// `threads` workers, see `CacheShape::fit`).
    pub fn new(source: BlockSource, storage: Storage, shape: CacheShape, threads: usize) -> Self {
        let values_per_texel = source.pairs() * 3;
        let blocks = source.texels().div_ceil(shape.texels_per_block);
        let per_shard_numbers = blocks.div_ceil(shape.shards);
        let shards = (0..shape.shards)
            .map(|_| {
                Mutex::new(Shard {
                    slots: Vec::with_capacity(shape.blocks_per_shard),
                    index: vec![ABSENT; per_shard_numbers],
                    hand: 0,
                })
            })
            .collect();
        Self {
            source,
            storage,
            shape,
            threads,
            values_per_texel,
            shards,
            reads: AtomicU64::new(0),
            error: OnceLock::new(),
        }
    }

    pub fn shape(&self) -> CacheShape {
        self.shape
    }
    pub fn storage(&self) -> Storage {
        self.storage
    }
    /// Most bytes of values the cache holds at once, resident and in flight.
    pub fn bytes(&self) -> u64 {
        let size = match self.storage {
            Storage::F16 => 2,
            Storage::F32 => 4,
        };
        self.shape
            .bytes(self.values_per_texel as u64 * size, self.threads)
    }
    /// Blocks read from disk so far.
    pub fn reads(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }
    pub fn error(&self) -> Option<&str> {
        self.error.get().map(String::as_str)
    }

    /// Texel `t`'s block and where in it the texel begins (in values), or None when
    /// the block cannot be read (the error is kept, see `error`).
    pub fn texel(&self, t: usize) -> Option<(Arc<Block>, usize)> {
        let block = t / self.shape.texels_per_block;
        let offset = (t - block * self.shape.texels_per_block) * self.values_per_texel;
        let (shard, local) = (block % self.shape.shards, block / self.shape.shards);
        let lock = || {
            self.shards[shard]
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
        };
        if let Some(values) = lock().get(local) {
            return Some((values, offset));
        }
        let values = Arc::new(self.read(block)?);
        let mut s = lock();
        // Another worker may have read it meanwhile: keep one copy.
        if let Some(values) = s.get(local) {
            return Some((values, offset));
        }
        s.insert(local, Arc::clone(&values), self.shape.blocks_per_shard);
        Some((values, offset))
    }

    fn read(&self, block: usize) -> Option<Block> {
        let first = block * self.shape.texels_per_block;
        let count = self
            .shape
            .texels_per_block
            .min(self.source.texels() - first);
        self.reads.fetch_add(1, Ordering::Relaxed);
        if self.storage == Storage::F16 {
            // An F16 file: its values as stored, no f32 buffer.
            let mut halves = vec![f16::ZERO; count * self.values_per_texel];
            match self.source.read_texels_f16(first, &mut halves) {
                Some(Ok(())) => return Some(Block::F16(halves.into_boxed_slice())),
                Some(Err(e)) => {
                    let _ = self.error.set(e);
                    return None;
                }
                None => {}
            }
        }
        let mut values = vec![0.0f32; count * self.values_per_texel];
        if let Err(e) = self.source.read_texels(first, &mut values) {
            let _ = self.error.set(e);
            return None;
        }
        Some(match self.storage {
            // Exact: the table is F16 only when every value is an f16.
            Storage::F16 => Block::F16(values.iter().map(|&x| f16::from_f32(x)).collect()),
            Storage::F32 => Block::F32(values.into_boxed_slice()),
        })
    }
}

#[cfg(test)]
#[path = "cache_tests.rs"]
mod tests;
