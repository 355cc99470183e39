//! A bounded cache of a `.btf`'s value blocks, read on demand from disk: how a
//! `BtfTable` shades a BTF whose values exceed its memory bound. A block is a run of
//! rows, a row being one texel's values for one light (`V * 3`: what one light of an
//! interpolation reads); a source that reads only whole texels gets blocks of whole
//! texels. Renderers look rows up from every rayon worker at once, so the cache is
//! split into shards (a block's shard is its number modulo the shard count, so
//! neighbouring blocks land on different locks), each a small mutex-guarded clock
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

/// Default block size: one row (a Bonn 81-view row is 486 bytes as f16, a UBO2014
/// 151-view row 906), so that a lookup reads only the row an interpolation weight
/// needs. A render sees every texel under lights that move little from frame to frame
/// and under the directions its material samples draw at random: the rows it reads
/// again are a small part of the BTF, larger blocks fill the bound with rows it does
/// not read again (`meso bench btf`, docs/performance.md: on a 2.6 GB BTF, 6-texel
/// blocks of 236 KB made frames 27 to 48 times slower than in memory at bounds of 64
/// MB to 1 GB, single rows 1.4 to 2.5 times, reading 4 to 7 MB a frame instead of 1.6
/// GB; 4 KB blocks as fast at 256 MB and 1 GB, 5 times slower at 64 MB).
pub const BLOCK_BYTES: u64 = 512;
/// Bytes each resident block costs besides its values: its slot, its `Arc` and the
/// allocator's headers (an estimate on the high side, so that the bound holds).
pub const BLOCK_OVERHEAD: u64 = 128;
/// Bytes of the index per block of the BTF (resident or not).
const INDEX_BYTES: u64 = 4;
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

/// How a cache is laid out: rows per block, resident blocks, shards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheShape {
    pub rows_per_block: usize,
    pub shards: usize,
    pub blocks_per_shard: usize,
}

impl CacheShape {
    /// The shape that keeps resident and in-flight blocks, their overhead and the
    /// index within `max_bytes` for `threads` workers, blocks of at most about
    /// `block_bytes` made of whole units of `unit_rows` rows of `row_bytes` each (at
    /// least one unit), or why no cache fits: the bound must hold one block besides
    /// the workers' and the index.
    pub fn fit(
        row_bytes: u64,
        unit_rows: usize,
        rows: usize,
        max_bytes: u64,
        block_bytes: u64,
        threads: usize,
    ) -> Result<Self, String> {
        let unit_rows = unit_rows.clamp(1, rows.max(1));
        let unit_bytes = row_bytes.max(1) * unit_rows as u64;
        let units = rows.div_ceil(unit_rows) as u64;
        let workers = TRANSIENT_BLOCKS_PER_THREAD * threads.max(1) as u64;
        // Under a tight bound, smaller blocks, so that a few stay resident besides
        // the workers' (down to one unit).
        let target = block_bytes.min(max_bytes / (workers + MIN_RESIDENT));
        let units_per_block = (target / unit_bytes).clamp(1, units.max(1));
        let rows_per_block = (units_per_block as usize * unit_rows).min(rows.max(1));
        let block = rows_per_block as u64 * row_bytes.max(1);
        let total_blocks = rows.div_ceil(rows_per_block) as u64;
        let index = (total_blocks + MAX_SHARDS as u64) * INDEX_BYTES;
        let transient = workers * block;
        let resident = max_bytes.saturating_sub(transient + index) / (block + BLOCK_OVERHEAD);
        if resident == 0 {
            return Err(format!(
                "a bound of {max_bytes} bytes holds no block of {block} bytes besides {transient} bytes in flight for {threads} threads and an index of {index} bytes: at least {} bytes are needed",
                transient + index + block + BLOCK_OVERHEAD
            ));
        }
        let resident = resident.min(total_blocks);
        let shards = (resident as usize).min(MAX_SHARDS);
        Ok(Self {
            rows_per_block,
            shards,
            blocks_per_shard: resident as usize / shards,
        })
    }

    /// Bytes the cache may hold at once: resident blocks with their overhead, blocks
    /// in flight, and the index over all `rows`.
    pub fn bytes(&self, row_bytes: u64, rows: usize, threads: usize) -> u64 {
        let block = self.rows_per_block as u64 * row_bytes;
        let index = (rows.div_ceil(self.rows_per_block) + MAX_SHARDS) as u64 * INDEX_BYTES;
        (self.shards * self.blocks_per_shard) as u64 * (block + BLOCK_OVERHEAD)
            + TRANSIENT_BLOCKS_PER_THREAD * threads.max(1) as u64 * block
            + index
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
    /// Lookups that found their block resident.
    hits: u64,
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

/// What a cache has done so far (`BlockCache::stats`), for reports and benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CacheStats {
    /// Lookups that found their block resident.
    pub hits: u64,
    /// Blocks read from the source (misses; a block two workers missed at once is
    /// read twice and counted twice).
    pub reads: u64,
    /// Bytes of values those reads delivered, in the precision held.
    pub bytes_read: u64,
    /// Seconds the workers spent in those reads, summed over the workers.
    pub read_seconds: f64,
}

/// A bounded, thread-safe cache of one BTF's value blocks (see the module comment).
pub struct BlockCache {
    source: BlockSource,
    storage: Storage,
    shape: CacheShape,
    threads: usize,
    /// Values per row: `V * 3`.
    values_per_row: usize,
    rows: usize,
    shards: Box<[Mutex<Shard>]>,
    /// Blocks read from disk, for tests and reports (misses, re-reads after eviction).
    reads: AtomicU64,
    bytes_read: AtomicU64,
    read_nanos: AtomicU64,
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
        let values_per_row = source.view_dirs().len() * 3;
        let rows = source.texels() * source.light_dirs().len();
        let blocks = rows.div_ceil(shape.rows_per_block);
        let per_shard_numbers = blocks.div_ceil(shape.shards);
        let shards = (0..shape.shards)
            .map(|_| {
                Mutex::new(Shard {
                    slots: Vec::with_capacity(shape.blocks_per_shard),
                    index: vec![ABSENT; per_shard_numbers],
                    hand: 0,
                    hits: 0,
                })
            })
            .collect();
        Self {
            source,
            storage,
            shape,
            threads,
            values_per_row,
            rows,
            shards,
            reads: AtomicU64::new(0),
            bytes_read: AtomicU64::new(0),
            read_nanos: AtomicU64::new(0),
            error: OnceLock::new(),
        }
    }

    pub fn shape(&self) -> CacheShape {
        self.shape
    }
    pub fn storage(&self) -> Storage {
        self.storage
    }
    fn value_size(&self) -> u64 {
        match self.storage {
            Storage::F16 => 2,
            Storage::F32 => 4,
        }
    }
    /// Most bytes the cache holds at once: resident and in-flight values, the
    /// resident blocks' overhead and the index.
    pub fn bytes(&self) -> u64 {
        self.shape.bytes(
            self.values_per_row as u64 * self.value_size(),
            self.rows,
            self.threads,
        )
    }
    /// Blocks read from disk so far.
    pub fn reads(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }
    /// Hits, reads, bytes read and time reading so far.
    pub fn stats(&self) -> CacheStats {
        let hits = self
            .shards
            .iter()
            .map(|s| s.lock().unwrap_or_else(PoisonError::into_inner).hits)
            .sum();
        CacheStats {
            hits,
            reads: self.reads(),
            bytes_read: self.bytes_read.load(Ordering::Relaxed),
            read_seconds: self.read_nanos.load(Ordering::Relaxed) as f64 * 1e-9,
        }
    }
    pub fn error(&self) -> Option<&str> {
        self.error.get().map(String::as_str)
    }

    /// Row `r`'s block (row `t * L + l`: texel `t`'s values for light `l`) and where
    /// in it the row begins (in values), or None when the block cannot be read (the
    /// error is kept, see `error`).
    pub fn row(&self, r: usize) -> Option<(Arc<Block>, usize)> {
        let block = r / self.shape.rows_per_block;
        let offset = (r - block * self.shape.rows_per_block) * self.values_per_row;
        let (shard, local) = (block % self.shape.shards, block / self.shape.shards);
        let lock = || {
            self.shards[shard]
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
        };
        {
            let mut s = lock();
            if let Some(values) = s.get(local) {
                s.hits += 1;
                return Some((values, offset));
            }
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
        let start = std::time::Instant::now();
        let first = block * self.shape.rows_per_block;
        let count = self.shape.rows_per_block.min(self.rows - first);
        let n = count * self.values_per_row;
        self.reads.fetch_add(1, Ordering::Relaxed);
        let done = |block: Block| {
            self.bytes_read
                .fetch_add(n as u64 * self.value_size(), Ordering::Relaxed);
            self.read_nanos
                .fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
            Some(block)
        };
        if self.storage == Storage::F16 {
            // An F16 file: its values as stored, no f32 buffer.
            let mut halves = vec![f16::ZERO; n];
            match self.source.read_rows_f16(first, &mut halves) {
                Some(Ok(())) => return done(Block::F16(halves.into_boxed_slice())),
                Some(Err(e)) => {
                    let _ = self.error.set(e);
                    return None;
                }
                None => {}
            }
        }
        let mut values = vec![0.0f32; n];
        if let Err(e) = self.source.read_rows(first, &mut values) {
            let _ = self.error.set(e);
            return None;
        }
        done(match self.storage {
            // Exact: the table is F16 only when every value is an f16.
            Storage::F16 => Block::F16(values.iter().map(|&x| f16::from_f32(x)).collect()),
            Storage::F32 => Block::F32(values.into_boxed_slice()),
        })
    }
}

#[cfg(test)]
#[path = "cache_tests.rs"]
mod tests;
