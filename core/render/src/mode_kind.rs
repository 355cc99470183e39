//! Which mode renders and where: the names a scene file, the command line and the
//! studio use for the render modes and the devices they run on.

/// The render modes (docs/rendering.md).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum ModeKind {
    /// Progressive ray tracing of SPMM and analytic materials (Silva & Santos 2013).
    #[default]
    Spmm,
    /// Bi-scale precomputed radiance transfer with biclustering (Sun et al. 2010).
    Biscale,
    /// Frequency-adaptive shading of measured BRDFs (Bagher et al. 2013).
    Adaptive,
}

impl ModeKind {
    pub const ALL: [ModeKind; 3] = [ModeKind::Spmm, ModeKind::Biscale, ModeKind::Adaptive];

    pub fn name(self) -> &'static str {
        match self {
            ModeKind::Spmm => "spmm",
            ModeKind::Biscale => "biscale",
            ModeKind::Adaptive => "adaptive",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// True if the mode's preparation depends on the geometry (biscale's transfer
    /// matrices), so a mesh change is a new preparation, which an editor runs in the
    /// background rather than as an edit on the render thread.
    pub fn prepares_geometry(self) -> bool {
        self == ModeKind::Biscale
    }
}

/// Where a mode runs.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Device {
    #[default]
    Cpu,
    Gpu,
}

impl Device {
    pub const ALL: [Device; 2] = [Device::Cpu, Device::Gpu];

    pub fn name(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Gpu => "gpu",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|d| d.name() == name)
    }
}
