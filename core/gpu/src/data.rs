//! The `data` words shaders read (`shaders/brdf.wgsl`, `shaders/spmm.wgsl`): BRDF
//! records, SPMM basis functions, prepared SPMM materials with their residual tables
//! and direction tables, and the material table. Floats are stored by their bits, so
//! one `array<u32>` binding serves every kind (adapters offer few storage bindings).

use meso_materials::brdf::{AnalyticBrdf, BasisFunction};
use meso_materials::btf::table::{BtfTable, BtfValues};
use meso_materials::merl::MerlBrdf;
use meso_materials::spmm::directions::DirectionTable;
use meso_materials::spmm::{PreparedSpmm, ResidualCells};

/// Words of one BRDF record (model + 7 parameters).
pub(super) const BRDF_WORDS: usize = 8;
/// Words of one basis function (BRDF record, frame x y z, selection albedo, padding).
pub(super) const BASIS_WORDS: usize = 20;
/// The word of a basis record holding its selection albedo (`shaders/spmm.wgsl`).
const BASIS_ALBEDO: usize = BRDF_WORDS + 9;
const SPMM_HEADER_WORDS: usize = 16;
const NO_CLUSTER: u32 = u32::MAX;

/// Bytes of the data words by kind, for `--json` and the status bar.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DataBytes {
    pub spmm_bases: u64,
    pub spmm_weights: u64,
    pub residual_tables: u64,
    pub materials: u64,
    /// MERL tables (f32, scaled as `MerlBrdf::cell_value`) and their sampling tables.
    pub merl_tables: u64,
    /// `btf` materials: their values, direction tables and lobe CDFs (once per table).
    pub btf_tables: u64,
}

/// Where a `btf` table's shared words sit (`Words::push_btf_table`).
#[derive(Clone, Copy, Debug)]
pub(super) struct BtfWords {
    values_at: u32,
    half: u32,
    lights_at: u32,
    views_at: u32,
    lobe_at: u32,
}

/// A growing word buffer.
#[derive(Default)]
pub(super) struct Words {
    pub words: Vec<u32>,
    pub bytes: DataBytes,
}

fn f(v: f64) -> u32 {
    (v as f32).to_bits()
}

impl Words {
    pub fn at(&self) -> u32 {
        u32::try_from(self.words.len())
            .expect("GPU data fits in 2^32 words (checked by the caller)")
    }

    fn push_f32s(&mut self, values: impl IntoIterator<Item = f32>) -> u32 {
        let at = self.at();
        self.words.extend(values.into_iter().map(f32::to_bits));
        at
    }

    /// Half floats two to a word, the low half first (`unpack2x16float`), the last
    /// word's high half zero when the count is odd.
    fn push_halves(&mut self, values: impl IntoIterator<Item = half::f16>) -> u32 {
        let at = self.at();
        let mut values = values.into_iter();
        while let Some(lo) = values.next() {
            let hi = values.next().map_or(0, |h| u32::from(h.to_bits()));
            self.words.push(u32::from(lo.to_bits()) | (hi << 16));
        }
        at
    }

    fn push_u32s(&mut self, values: impl IntoIterator<Item = u32>) -> u32 {
        let at = self.at();
        self.words.extend(values);
        at
    }

    /// One BRDF record; returns its offset.
    pub fn push_brdf(&mut self, brdf: &AnalyticBrdf) -> u32 {
        let at = self.at();
        let model = meso_materials::brdf::BrdfModel::ALL
            .iter()
            .position(|m| *m == brdf.model())
            .expect("a known model") as u32;
        let mut record = [0u32; BRDF_WORDS];
        record[0] = model;
        let params: Vec<f64> = match brdf {
            // The shader reads Oren-Nayar's A and B, as the CPU model precomputes them.
            AnalyticBrdf::OrenNayar(b) => {
                let s2 = b.sigma() * b.sigma();
                vec![1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)]
            }
            other => other.param_values(),
        };
        for (slot, p) in record[1..].iter_mut().zip(params) {
            *slot = f(p);
        }
        self.words.extend_from_slice(&record);
        at
    }

    /// One basis function: its BRDF and its own frame.
    pub fn push_basis(&mut self, basis: &BasisFunction) -> u32 {
        let at = self.push_brdf(basis.brdf());
        let fr = basis.frame();
        for v in [fr.x, fr.y, fr.z] {
            self.words.extend([f(v.x), f(v.y), f(v.z)]);
        }
        self.words
            .extend(std::iter::repeat_n(0, BASIS_WORDS - BRDF_WORDS - 9));
        at
    }

    /// A direction table: `[points, points_at, triangles_at, cell_starts_at,
    /// cell_triangles_at, hull_len, hull_at]` and its arrays.
    fn push_direction_table(&mut self, table: &DirectionTable) -> u32 {
        let parts = table.parts();
        let (points, triangles, hull) = (parts.points, parts.triangles, parts.hull);
        let points_at = self.push_f32s(points.iter().flat_map(|p| [p.x as f32, p.y as f32]));
        let triangles_at = self.push_u32s(triangles.iter().flatten().copied());
        let cell_tris_at = self.push_u32s(parts.cell_triangles.iter().copied());
        let starts_at = self.push_u32s(parts.cell_starts.iter().copied());
        let hull_at = self.push_u32s(hull.iter().copied());
        self.push_u32s([
            points.len() as u32,
            points_at,
            triangles_at,
            starts_at,
            cell_tris_at,
            hull.len() as u32,
            hull_at,
        ])
    }

    /// A prepared SPMM material with its texture tiling; returns its header's offset.
    /// `used` (per cluster; `None`: all) leaves out the bases of clusters no ray can
    /// reach (`reach.rs`); the residual tables of those were left out by the
    /// preparation.
    pub fn push_spmm(
        &mut self,
        prepared: &PreparedSpmm,
        uv_scale: glam::DVec2,
        used: Option<&[bool]>,
    ) -> u32 {
        let p = prepared.parts();
        let start = self.words.len();
        // Basis records of every used cluster, then per cluster the offset of its first.
        let mut cluster_bases = Vec::with_capacity(p.bases.len());
        for (c, (cluster, albedos)) in p.bases.iter().zip(p.basis_albedo).enumerate() {
            if used.is_some_and(|u| !u.get(c).copied().unwrap_or(false)) {
                cluster_bases.push(NO_CLUSTER);
                continue;
            }
            cluster_bases.push(self.at());
            for (b, &albedo) in cluster.iter().zip(albedos) {
                let at = self.push_basis(b) as usize;
                // How often the pack sampler draws this basis (`PreparedSpmm::sample_texel`).
                self.words[at + BASIS_ALBEDO] = f(albedo);
            }
        }
        let cluster_bases_at = self.push_u32s(cluster_bases);
        let bases_end = self.words.len();
        let texel_cluster_at = self.push_u32s(p.texel_cluster.iter().copied());
        let offsets_at = self.push_u32s(p.offsets.iter().copied());
        let basis_at = self.push_u32s(p.basis.iter().map(|&b| u32::from(b)));
        let rgb_at = self.push_f32s(p.rgb.iter().flatten().copied());
        let weights_end = self.words.len();
        let (mut has_residual, mut k, mut cluster_cells_at, mut coef_at) = (0, 0, 0, 0);
        let (mut lights_at, mut views_at, mut residual_half) = (0, 0, 0);
        if let Some(r) = &p.residual {
            has_residual = 1;
            k = r.k as u32;
            // Half-float tables go up two values to a word (half the device bytes and
            // the loads; the same values), so a cluster's cells start at a value index:
            // twice the word index for halves.
            let first_value = match &r.cells {
                ResidualCells::F16(cells) => {
                    residual_half = 1;
                    2 * self.push_halves(cells.iter().copied())
                }
                ResidualCells::F32(cells) => self.push_f32s(cells.iter().copied()),
            };
            cluster_cells_at = self.push_u32s(
                r.cluster_offset
                    .iter()
                    .map(|o| o.map_or(NO_CLUSTER, |o| first_value + o as u32)),
            );
            coef_at = self.push_f32s(r.coefficients.iter().copied());
            lights_at = self.push_direction_table(r.lights);
            views_at = self.push_direction_table(r.views);
        }
        let residual_end = self.words.len();
        let mut header = [0u32; SPMM_HEADER_WORDS];
        header[..16].copy_from_slice(&[
            p.width,
            p.height,
            texel_cluster_at,
            offsets_at,
            basis_at,
            rgb_at,
            cluster_bases_at,
            has_residual,
            k,
            cluster_cells_at,
            coef_at,
            lights_at,
            views_at,
            f(uv_scale.x),
            f(uv_scale.y),
            residual_half,
        ]);
        let at = self.push_u32s(header);
        self.bytes.spmm_bases += 4 * (bases_end - start) as u64;
        self.bytes.spmm_weights += 4 * (weights_end - bases_end + SPMM_HEADER_WORDS) as u64;
        self.bytes.residual_tables += 4 * (residual_end - weights_end) as u64;
        at
    }

    /// A `btf` material as `shaders/btf.wgsl` reads it: the table's words
    /// (`push_btf_table`) and the material's header (`push_btf_header`). Returns the
    /// header's offset, or `None` for a table read from disk block by block (it has
    /// no values in memory to upload; `GpuSpmmMode::supports` refuses those by name).
    #[cfg(test)]
    pub fn push_btf(&mut self, table: &BtfTable, uv_scale: glam::DVec2) -> Option<u32> {
        let words = self.push_btf_table(table)?;
        Some(self.push_btf_header(table, words, uv_scale))
    }

    /// What every material showing `table` shares, pushed once: the values
    /// `[texel][light][view][rgb]` as they are held (f16 two to a word, low half
    /// first, or f32), the light and view direction tables (as the residual's) and
    /// the lobe sampler's CDFs (`BtfTable::lobe`, f32 as the CPU holds them). `None`
    /// for a table without its values in memory.
    pub fn push_btf_table(&mut self, table: &BtfTable) -> Option<BtfWords> {
        let p = table.parts()?;
        let start = self.words.len();
        let (values_at, half) = match p.values {
            BtfValues::F16(v) => (self.push_halves(v.iter().copied()), 1),
            BtfValues::F32(v) => (self.push_f32s(v.iter().copied()), 0),
        };
        let words = BtfWords {
            values_at,
            half,
            lights_at: self.push_direction_table(p.lights),
            views_at: self.push_direction_table(p.views),
            lobe_at: self.push_f32s(table.lobe().cdfs().iter().copied()),
        };
        self.bytes.btf_tables += 4 * (self.words.len() - start) as u64;
        Some(words)
    }

    /// One material's header over a table's words: `[width, height, lights, views,
    /// values_at, f16, light_table, view_table, uv_scale x, y, lobe]`. Returns its
    /// offset.
    pub fn push_btf_header(
        &mut self,
        table: &BtfTable,
        words: BtfWords,
        uv_scale: glam::DVec2,
    ) -> u32 {
        let header = [
            table.width(),
            table.height(),
            table.light_dirs().len() as u32,
            table.view_dirs().len() as u32,
            words.values_at,
            words.half,
            words.lights_at,
            words.views_at,
            f(uv_scale.x),
            f(uv_scale.y),
            words.lobe_at,
        ];
        self.bytes.btf_tables += 4 * header.len() as u64;
        self.push_u32s(header)
    }

    /// A MERL table as `shaders/merl.wgsl` reads it: a header of offsets (the table,
    /// the sampler's cell probabilities, row and column CDFs) and the albedo at normal
    /// view (RGB f32, the denoiser's guide: `shaders/guides.wgsl`), the table's cells
    /// scaled as `MerlBrdf::cell_value` (cells without data 0), and the CPU sampler's
    /// own tables in f32. Returns the header's offset.
    pub fn push_merl(&mut self, brdf: &MerlBrdf) -> u32 {
        let start = self.words.len();
        let table_at = self.push_f32s((0..meso_materials::merl::CELLS).flat_map(|c| {
            let v = brdf.cell_value(c);
            [v.x as f32, v.y as f32, v.z as f32]
        }));
        let (prob, rows, cols) = brdf.sampler().tables();
        let prob_at = self.push_f32s(prob.iter().map(|&p| p as f32));
        let rows_at = self.push_f32s(rows.iter().map(|&p| p as f32));
        let cols_at = self.push_f32s(cols.iter().map(|&p| p as f32));
        let albedo = brdf.albedo_at_normal().as_vec3();
        let at = self.push_u32s([
            table_at,
            prob_at,
            rows_at,
            cols_at,
            albedo.x.to_bits(),
            albedo.y.to_bits(),
            albedo.z.to_bits(),
        ]);
        self.bytes.merl_tables += 4 * (self.words.len() - start) as u64;
        at
    }
}
