//! The MERL binary file: three little-endian int32 dimensions (90, 90, 180), then the
//! red, green and blue blocks of 1,458,000 little-endian float64 each, 34,992,012
//! bytes in all. Reading checks the size (from the file system, before anything is
//! allocated) and the dimensions, then every value (`MerlBrdf::from_stored`); writing
//! streams through `write_atomic`, so a failed write leaves the old file as it was.

use std::io::{Read, Write};
use std::path::Path;

use super::{CELLS, MerlBrdf, MerlError, MerlFault, PHI_D_RES, THETA_D_RES, THETA_H_RES};
use crate::atomic::write_atomic;

const HEADER_BYTES: usize = 12;
const DIMENSIONS: [i32; 3] = [THETA_H_RES as i32, THETA_D_RES as i32, PHI_D_RES as i32];
/// The exact size of a MERL file: 12 + 3 * 1,458,000 * 8 = 34,992,012 bytes.
pub const FILE_BYTES: u64 = (HEADER_BYTES + 3 * CELLS * 8) as u64;

/// Byte offset of one stored value in the file.
pub(super) fn value_offset(channel: usize, cell: usize) -> usize {
    HEADER_BYTES + (channel * CELLS + cell) * 8
}

fn dimensions(header: &[u8]) -> [i32; 3] {
    let dim = |k: usize| {
        let b: [u8; 4] = header[4 * k..4 * k + 4]
            .try_into()
            .expect("the header slice holds three int32");
        i32::from_le_bytes(b)
    };
    [dim(0), dim(1), dim(2)]
}

/// The header fault, if any, of a file of `len` bytes whose first bytes are `head`
/// (at most 12): wrong dimensions are named before a wrong size, since they say what
/// the file is (another resolution) rather than only that it is not the right one.
fn check_header(head: &[u8], len: u64) -> Result<(), MerlFault> {
    if head.len() >= HEADER_BYTES {
        let found = dimensions(head);
        if found != DIMENSIONS {
            return Err(MerlFault::Dimensions { found });
        }
    }
    if len != FILE_BYTES {
        return Err(MerlFault::Size { found: len });
    }
    Ok(())
}

impl MerlBrdf {
    /// Reads and validates a MERL file. The size is checked against the file system
    /// before the 35 MB are read, so a wrong file costs nothing.
    pub fn read(path: &Path) -> Result<Self, MerlError> {
        let io = |e| MerlError::at(path, MerlFault::Io(e));
        let mut f = std::fs::File::open(path).map_err(io)?;
        let len = f.metadata().map_err(io)?.len();
        if len != FILE_BYTES {
            let mut head = Vec::with_capacity(HEADER_BYTES);
            (&mut f)
                .take(HEADER_BYTES as u64)
                .read_to_end(&mut head)
                .map_err(io)?;
            check_header(&head, len).map_err(|fault| MerlError::at(path, fault))?;
        }
        let mut bytes = vec![0u8; FILE_BYTES as usize];
        f.read_exact(&mut bytes).map_err(io)?;
        // The file may have grown since the size check; a longer file is still wrong.
        let mut probe = [0u8; 1];
        if f.read(&mut probe).map_err(io)? != 0 {
            let len = f.metadata().map_err(io)?.len();
            return Err(MerlError::at(path, MerlFault::Size { found: len }));
        }
        Self::from_bytes(&bytes).map_err(|e| MerlError::at(path, e.fault))
    }

    /// Parses and validates the bytes of a MERL file.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, MerlError> {
        check_header(&bytes[..bytes.len().min(HEADER_BYTES)], bytes.len() as u64)?;
        let mut stored = vec![[0.0f64; 3]; CELLS];
        for (channel, block) in bytes[HEADER_BYTES..].chunks_exact(CELLS * 8).enumerate() {
            for (s, b) in stored.iter_mut().zip(block.chunks_exact(8)) {
                s[channel] = f64::from_le_bytes(b.try_into().expect("chunks of 8 bytes"));
            }
        }
        Self::from_stored(stored)
    }

    /// The file's bytes (34,992,012 of them).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES as usize);
        self.write_to(&mut out)
            .expect("writing to a Vec<u8> cannot fail");
        out
    }

    /// Writes the file atomically: whole or not at all.
    pub fn write(&self, path: &Path) -> Result<(), MerlError> {
        write_atomic(path, |w| self.write_to(w))
            .map_err(|e| MerlError::at(path, MerlFault::Write(e)))
    }

    fn write_to(&self, w: &mut dyn Write) -> std::io::Result<()> {
        for d in DIMENSIONS {
            w.write_all(&d.to_le_bytes())?;
        }
        let mut block = Vec::with_capacity(CELLS * 8);
        for channel in 0..3 {
            block.clear();
            for s in self.stored() {
                block.extend_from_slice(&s[channel].to_le_bytes());
            }
            w.write_all(&block)?;
        }
        Ok(())
    }
}
