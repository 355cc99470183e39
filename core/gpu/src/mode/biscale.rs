//! The GPU mode's frames for the biscale mode (`shaders/biscale.wgsl`): the same
//! skeleton, film, lights and ambient term as the spmm mode, with the precomputed
//! environment (`crate::biscale`) in place of the environment's path samples. Its
//! words follow the environment's in `env`; `Params::biscale` says where.

use super::*;
use crate::biscale::BiscaleBlock;

/// The `env` words: the environment's and background's, then the biscale words.
pub(super) fn env_words(
    scene: &Scene,
    sampling: &environment::MapSampling,
    biscale: Option<&BiscaleBlock>,
) -> Vec<u32> {
    let mut words = environment::words(scene, sampling);
    if let Some(b) = biscale {
        words.extend_from_slice(&b.words);
    }
    words
}

impl GpuSpmmMode {
    /// The device half of the biscale mode: `scene` with its BVH (the one the CPU's
    /// precomputation traced) and the biscale words, on `ctx`. The returned mode
    /// renders the biscale image; `meso_modes`' `GpuBiscaleMode` wraps it.
    pub fn prepare_biscale(
        ctx: GpuContext,
        scene: Scene,
        (width, height): (u32, u32),
        prepare: Prepare,
        bvh: SceneBvh,
        block: BiscaleBlock,
    ) -> Result<Self, ModeError> {
        Self::prepare_with(
            ctx,
            scene,
            (width, height),
            prepare,
            false,
            Frames::Biscale(Box::new((bvh, block))),
        )
    }

    /// New biscale words (a new L* after a light change, new tables after a material
    /// edit, a new precomputation after new meshes), uploaded with the environment's.
    /// The film is left as it is: the edit that made them restarted what it changed.
    pub fn replace_biscale(&mut self, block: BiscaleBlock) -> Result<(), EditError> {
        if self.biscale.is_none() {
            return Err(EditError::Size(
                "this device mode renders spmm frames, not biscale ones".into(),
            ));
        }
        let words = env_words(&self.core.scene, &self.env_sampling, Some(&block));
        if let Some(p) = words_size_problem(&self.ctx, ENVIRONMENT_WORDS, words.len()) {
            return Err(EditError::Size(p));
        }
        self.biscale = Some(block);
        self.env_words = words;
        self.rebind();
        Ok(())
    }

    /// Bytes of the biscale words on the device (zero for spmm frames).
    pub fn biscale_bytes(&self) -> crate::biscale::BiscaleBytes {
        self.biscale.as_ref().map(|b| b.bytes).unwrap_or_default()
    }

    /// Where the biscale words start in `env` (0 without them: never read then).
    pub(super) fn biscale_at(&self) -> u32 {
        match &self.biscale {
            Some(b) => (self.env_words.len() - b.words.len()) as u32,
            None => 0,
        }
    }
}
