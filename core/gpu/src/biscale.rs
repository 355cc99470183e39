//! What the biscale mode uploads for its device frames (`shaders/biscale.wgsl`): the
//! CPU prepares everything (the precomputation, the BTF tables, the environment's
//! split, L* = T L) in `meso-modes`, which hands it over as plain arrays; this module
//! checks them and lays them out as words behind a header of offsets. The words are
//! appended to the `env` buffer (the integrator's eight storage bindings are WebGPU's
//! default limit, so there is no room for a ninth).

use meso_materials::image::Image;
use meso_render::environment::EnvironmentSampler;

/// Header words (`BIS_*` in `shaders/biscale.wgsl`).
const HEADER_WORDS: usize = 20;
/// `LEAF_BIT` of the shader: a quadtree node that is a leaf.
pub const LEAF_BIT: u32 = 0x8000_0000;
/// Table kinds (`TABLE_*` of the shader).
const TABLE_NONE: u32 = 0;
const TABLE_GRAY: u32 = 1;
const TABLE_RGB: u32 = 2;
const TABLE_CELLS: u32 = 3;
const TABLE_SPMM: u32 = 4;
/// An SPMM cluster with no rows on the device (no ray reaches it).
const NO_ROWS: u32 = u32::MAX;
/// Words of one cluster's entry in an SPMM table: basis rows' offset, bases, residual
/// rows' offset.
const SPMM_CLUSTER_WORDS: usize = 3;
/// The shader's bound on local cells (32 x 32, `BiscaleSettings::problem`'s largest).
const MAX_CELLS: u32 = 1024;

/// One material's part of eq. 3 on the device.
#[derive(Clone, Copy, Debug)]
pub enum BiscaleTable<'a> {
    /// Nothing shaded (a mirror: the ray is followed).
    None,
    /// One row per view ([view][M]) times an RGB albedo (analytic BRDFs).
    Gray { rows: &'a [f32], albedo: [f32; 3] },
    /// RGB rows, [view][channel][M] (MERL tables times their tint).
    Rgb { rows: &'a [f32] },
    /// Each cell's response at one jittered direction, evaluated by the device's own
    /// material code (`btf` materials, which have no table on the CPU either).
    Cells,
    /// An SPMM pack: per cluster its rows (none for a cluster no ray reaches, which
    /// then costs nothing); the texels' weights, clusters and PCA coefficients are
    /// the pack the GPU spmm mode uploads for its own shading (the material record's).
    Spmm {
        /// Per cluster of the pack; `None`: not uploaded.
        clusters: &'a [Option<SpmmRows<'a>>],
        /// The residual's PCA terms tabulated (0 without a residual in use).
        terms: u32,
    },
}

/// One SPMM cluster's biscale rows.
#[derive(Clone, Copy, Debug, Default)]
pub struct SpmmRows<'a> {
    /// [basis][view][M], one tabulated row per basis function of the cluster.
    pub bases: &'a [f32],
    /// [term (mean, then the components)][view][channel][M]; empty without a residual.
    pub residual: &'a [f32],
}

/// The CPU's preparation, as the device reads it.
#[derive(Clone, Copy, Debug)]
pub struct BiscaleInputs<'a> {
    /// Local directions per side (M = res^2) and tabulated views per side.
    pub local_res: u32,
    pub view_res: u32,
    /// Per mesh, the index of its first triangle in `roots`.
    pub mesh_first: &'a [u32],
    /// Per scene triangle, its quadtree's root node.
    pub roots: &'a [u32],
    /// Quadtree nodes: `LEAF_BIT | leaf`, or the first of four consecutive children.
    pub nodes: &'a [u32],
    /// Per leaf, its three refined vertices (indices into L*'s vertices).
    pub leaves: &'a [[u32; 3]],
    /// Per refined vertex, L* laid out [channel][M]; `None` without an environment.
    pub lstar: Option<&'a [f32]>,
    /// Per material.
    pub tables: &'a [BiscaleTable<'a>],
    /// The environment's traced part (its brightest pixels) and its sampler.
    pub peaks: Option<(&'a Image, &'a EnvironmentSampler)>,
}

/// Bytes of the biscale words by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BiscaleBytes {
    pub lstar: u64,
    pub tables: u64,
    pub quadtrees: u64,
    pub peaks: u64,
}

impl BiscaleBytes {
    pub fn total(&self) -> u64 {
        self.lstar + self.tables + self.quadtrees + self.peaks
    }
}

/// The encoded words (offsets relative to their own start).
#[derive(Clone, Debug)]
pub struct BiscaleBlock {
    pub(crate) words: Vec<u32>,
    pub bytes: BiscaleBytes,
}

fn bits(v: f32) -> u32 {
    v.to_bits()
}

impl BiscaleBlock {
    /// Checks `inputs` (every index the shader follows lands inside its array; sizes
    /// agree with the resolutions) and lays them out; `Err` names what is wrong.
    pub fn encode(inputs: &BiscaleInputs) -> Result<Self, String> {
        let i = inputs;
        if !(1..=32).contains(&i.local_res) || !(1..=64).contains(&i.view_res) {
            return Err(format!(
                "biscale resolutions {} x {} local, {} x {} views are outside 1..=32 and 1..=64",
                i.local_res, i.local_res, i.view_res, i.view_res
            ));
        }
        let m = (i.local_res * i.local_res) as usize;
        debug_assert!(m as u32 <= MAX_CELLS);
        let views = (i.view_res * i.view_res) as usize;
        let vertices = i.lstar.map_or(0, |l| l.len() / (3 * m));
        if let Some(l) = i.lstar
            && l.len() % (3 * m) != 0
        {
            return Err(format!(
                "L* has {} values, not a multiple of 3 x {m}",
                l.len()
            ));
        }
        if let Some(t) = i.mesh_first.iter().find(|&&t| t as usize > i.roots.len()) {
            return Err(format!(
                "a mesh starts at triangle {t} of {}",
                i.roots.len()
            ));
        }
        if let Some(r) = i.roots.iter().find(|&&r| r as usize >= i.nodes.len()) {
            return Err(format!(
                "a quadtree root {r} lies past {} nodes",
                i.nodes.len()
            ));
        }
        for &n in i.nodes {
            let bad = if n & LEAF_BIT != 0 {
                (n & !LEAF_BIT) as usize >= i.leaves.len()
            } else {
                n as usize + 4 > i.nodes.len()
            };
            if bad {
                return Err(format!("quadtree node {n:#x} points past its arrays"));
            }
        }
        if i.lstar.is_some()
            && let Some(v) = i.leaves.iter().flatten().find(|&&v| v as usize >= vertices)
        {
            return Err(format!("a leaf uses vertex {v} of {vertices}"));
        }
        let mut w = vec![0u32; HEADER_WORDS];
        let mut bytes = BiscaleBytes::default();
        w[0] = m as u32;
        w[1] = i.local_res;
        w[2] = i.view_res;
        w[3] = u32::from(i.lstar.is_some());
        let quad_start = w.len();
        w[4] = w.len() as u32;
        w.extend_from_slice(i.mesh_first);
        w[5] = w.len() as u32;
        w.extend_from_slice(i.roots);
        w[6] = w.len() as u32;
        w.extend_from_slice(i.nodes);
        w[7] = w.len() as u32;
        w.extend(i.leaves.iter().flatten());
        bytes.quadtrees = 4 * (w.len() - quad_start) as u64;
        w[8] = w.len() as u32;
        if let Some(l) = i.lstar {
            w.extend(l.iter().map(|&v| bits(v)));
            bytes.lstar = 4 * l.len() as u64;
        }
        // Per material two words (kind, offset), then the tables.
        let table_start = w.len();
        w[9] = w.len() as u32;
        w.resize(w.len() + 2 * i.tables.len(), 0);
        for (k, t) in i.tables.iter().enumerate() {
            let at = w.len() as u32;
            let kind = match t {
                BiscaleTable::None => TABLE_NONE,
                BiscaleTable::Gray { rows, albedo } => {
                    check_rows(k, rows.len(), views * m)?;
                    w.extend(albedo.iter().map(|&v| bits(v)));
                    w.extend(rows.iter().map(|&v| bits(v)));
                    TABLE_GRAY
                }
                BiscaleTable::Rgb { rows } => {
                    check_rows(k, rows.len(), views * 3 * m)?;
                    w.extend(rows.iter().map(|&v| bits(v)));
                    TABLE_RGB
                }
                BiscaleTable::Cells => TABLE_CELLS,
                BiscaleTable::Spmm { clusters, terms } => {
                    encode_spmm(&mut w, k, clusters, *terms, views * m)?;
                    TABLE_SPMM
                }
            };
            let slot = table_start + 2 * k;
            w[slot] = kind;
            w[slot + 1] = at;
        }
        bytes.tables = 4 * (w.len() - table_start) as u64;
        if let Some((image, sampler)) = i.peaks {
            let start = w.len();
            let (rows, cols, pdfs) = sampler.tables();
            w[10] = 1;
            w[11] = image.width();
            w[12] = image.height();
            w[13] = w.len() as u32;
            w.extend(rows.iter().map(|&v| bits(v as f32)));
            w[14] = w.len() as u32;
            w.extend(cols.iter().map(|&v| bits(v as f32)));
            w[15] = w.len() as u32;
            w.extend(pdfs.map(|v| bits(v as f32)));
            w[16] = w.len() as u32;
            w.extend(image.pixels().iter().flatten().map(|&v| bits(v)));
            bytes.peaks = 4 * (w.len() - start) as u64;
        }
        if u32::try_from(w.len()).is_err() {
            return Err(format!(
                "{} biscale words do not fit 32-bit offsets",
                w.len()
            ));
        }
        Ok(Self { words: w, bytes })
    }
}

/// An SPMM table: the cluster count and the terms, per cluster its entry
/// (`SPMM_CLUSTER_WORDS`, offsets from the biscale words' start), then the rows.
/// `row` is one row's length, views x M.
fn encode_spmm(
    w: &mut Vec<u32>,
    material: usize,
    clusters: &[Option<SpmmRows>],
    terms: u32,
    row: usize,
) -> Result<(), String> {
    let head = w.len();
    w.push(clusters.len() as u32);
    w.push(terms);
    w.resize(w.len() + SPMM_CLUSTER_WORDS * clusters.len(), NO_ROWS);
    let residual_len = (1 + terms as usize) * 3 * row;
    for (c, rows) in clusters.iter().enumerate() {
        let Some(rows) = rows else { continue };
        if rows.bases.len() % row != 0 {
            return Err(format!(
                "material {material}'s cluster {c} has {} basis values, not a multiple of {row}",
                rows.bases.len()
            ));
        }
        if !rows.residual.is_empty() && rows.residual.len() != residual_len {
            return Err(format!(
                "material {material}'s cluster {c} has {} residual values, not {residual_len}",
                rows.residual.len()
            ));
        }
        let entry = head + 2 + SPMM_CLUSTER_WORDS * c;
        w[entry] = w.len() as u32;
        w[entry + 1] = (rows.bases.len() / row) as u32;
        w.extend(rows.bases.iter().map(|&v| bits(v)));
        if !rows.residual.is_empty() {
            w[entry + 2] = w.len() as u32;
            w.extend(rows.residual.iter().map(|&v| bits(v)));
        }
    }
    Ok(())
}

fn check_rows(material: usize, got: usize, want: usize) -> Result<(), String> {
    if got == want {
        Ok(())
    } else {
        Err(format!(
            "material {material}'s biscale table has {got} values, not {want}"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs<'a>(
        nodes: &'a [u32],
        leaves: &'a [[u32; 3]],
        lstar: &'a [f32],
        tables: &'a [BiscaleTable<'a>],
    ) -> BiscaleInputs<'a> {
        BiscaleInputs {
            local_res: 2,
            view_res: 1,
            mesh_first: &[0],
            roots: &[0],
            nodes,
            leaves,
            lstar: Some(lstar),
            tables,
            peaks: None,
        }
    }

    #[test]
    fn good_inputs_are_laid_out_behind_the_header() {
        let lstar: Vec<f32> = (0..3 * 3 * 4).map(|v| v as f32).collect();
        let rows = [0.5f32; 4];
        let tables = [BiscaleTable::Gray {
            rows: &rows,
            albedo: [1.0, 2.0, 3.0],
        }];
        let b = BiscaleBlock::encode(&inputs(&[LEAF_BIT], &[[0, 1, 2]], &lstar, &tables))
            .expect("valid");
        let w = &b.words;
        assert_eq!(w[0], 4);
        assert_eq!(w[w[6] as usize], LEAF_BIT);
        assert_eq!(&w[w[7] as usize..w[7] as usize + 3], &[0, 1, 2]);
        assert_eq!(f32::from_bits(w[w[8] as usize + 5]), 5.0);
        let table = w[9] as usize;
        assert_eq!(w[table], TABLE_GRAY);
        let at = w[table + 1] as usize;
        assert_eq!(f32::from_bits(w[at + 2]), 3.0);
        assert_eq!(f32::from_bits(w[at + 3]), 0.5);
        assert_eq!(b.bytes.lstar, 4 * lstar.len() as u64);
    }

    #[test]
    fn indices_past_their_arrays_and_wrong_sizes_are_refused() {
        let lstar = vec![0.0f32; 3 * 3 * 4];
        let rows = [0.5f32; 4];
        let gray = [BiscaleTable::Gray {
            rows: &rows,
            albedo: [1.0; 3],
        }];
        let err = |nodes: &[u32], leaves: &[[u32; 3]], lstar: &[f32], t: &[BiscaleTable]| {
            BiscaleBlock::encode(&inputs(nodes, leaves, lstar, t)).expect_err("refused")
        };
        assert!(err(&[LEAF_BIT | 1], &[[0, 1, 2]], &lstar, &gray).contains("points past"));
        assert!(err(&[1], &[[0, 1, 2]], &lstar, &gray).contains("points past"));
        assert!(err(&[LEAF_BIT], &[[0, 1, 3]], &lstar, &gray).contains("vertex 3 of 3"));
        assert!(err(&[LEAF_BIT], &[[0, 1, 2]], &lstar[1..], &gray).contains("multiple"));
        let short = [BiscaleTable::Rgb { rows: &rows }];
        assert!(err(&[LEAF_BIT], &[[0, 1, 2]], &lstar, &short).contains("not 12"));
    }

    /// An SPMM table: a cluster not uploaded has no rows and its entry says so; a
    /// cluster's rows land where its entry points; rows of the wrong size are refused.
    #[test]
    fn spmm_rows_go_up_for_the_clusters_uploaded_only() {
        let lstar = vec![0.0f32; 3 * 3 * 4];
        // One view, four cells: a row is 4 values; two bases, one residual term.
        let bases: Vec<f32> = (0..8).map(|v| v as f32).collect();
        let residual: Vec<f32> = (0..2 * 3 * 4).map(|v| 100.0 + v as f32).collect();
        let clusters = [
            None,
            Some(SpmmRows {
                bases: &bases,
                residual: &residual,
            }),
        ];
        let tables = [BiscaleTable::Spmm {
            clusters: &clusters,
            terms: 1,
        }];
        let b = BiscaleBlock::encode(&inputs(&[LEAF_BIT], &[[0, 1, 2]], &lstar, &tables))
            .expect("valid");
        let w = &b.words;
        let table = w[9] as usize;
        assert_eq!(w[table], TABLE_SPMM);
        let at = w[table + 1] as usize;
        assert_eq!(&w[at..at + 2], &[2, 1]);
        assert_eq!(&w[at + 2..at + 5], &[NO_ROWS, NO_ROWS, NO_ROWS]);
        let entry = &w[at + 5..at + 8];
        assert_eq!(entry[1], 2, "two bases");
        assert_eq!(f32::from_bits(w[entry[0] as usize + 5]), 5.0);
        assert_eq!(f32::from_bits(w[entry[2] as usize + 7]), 107.0);
        // The header, the entries and exactly the one cluster's rows.
        let words = 2 + 2 * 3 + bases.len() + residual.len();
        assert_eq!(b.bytes.tables, 4 * (2 + words) as u64);
        let short = [Some(SpmmRows {
            bases: &bases[1..],
            residual: &[],
        })];
        let bad = [BiscaleTable::Spmm {
            clusters: &short,
            terms: 0,
        }];
        let e = BiscaleBlock::encode(&inputs(&[LEAF_BIT], &[[0, 1, 2]], &lstar, &bad))
            .expect_err("refused");
        assert!(e.contains("not a multiple of 4"), "{e}");
        let wrong = [Some(SpmmRows {
            bases: &bases,
            residual: &residual[3..],
        })];
        let bad = [BiscaleTable::Spmm {
            clusters: &wrong,
            terms: 1,
        }];
        let e = BiscaleBlock::encode(&inputs(&[LEAF_BIT], &[[0, 1, 2]], &lstar, &bad))
            .expect_err("refused");
        assert!(e.contains("not 24"), "{e}");
    }
}
