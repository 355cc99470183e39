//! What an edit costs the GPU mode once the progressive skeleton has applied it:
//! the device's own size checks first, then re-uploads, rebinds and the restarts.

use super::*;

impl GpuSpmmMode {
    pub(super) fn apply_edit(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        if let SceneEdit::Material { index, material } = &edit
            && let Some(part) = unshaded(&self.core.scene, *index, material)
        {
            Unsupported::check(ModeKind::Spmm, Device::Gpu, vec![part])?;
        }
        let env_words = match &edit {
            SceneEdit::Environment(e) => environment::word_count(
                e.as_ref(),
                &self.core.scene.background,
                self.env_sampling.split,
            ),
            SceneEdit::Background(b) => environment::word_count(
                self.core.scene.environment.as_ref(),
                b,
                self.env_sampling.split,
            ),
            _ => 0,
        };
        if let Some(p) = words_size_problem(&self.ctx, ENVIRONMENT_WORDS, env_words) {
            return Err(EditError::Size(p));
        }
        if let SceneEdit::AddLight(_) = edit {
            let (w, h) = (self.core.film.width(), self.core.film.height());
            let layers = meso_render::layers::FIRST_LIGHT + self.core.scene.lights.len() + 1;
            let layers = if self.core.scene.lights.len() < MANY_LIGHTS {
                layers
            } else {
                meso_render::layers::SHARED_LIGHTS + 1
            };
            if let Some(p) =
                device_size_problem(&self.ctx, (w, h), layers, self.core.film.aux_words())
            {
                return Err(EditError::Size(p));
            }
        }
        let meshes_before =
            matches!(edit, SceneEdit::Meshes(_)).then(|| self.core.scene.meshes.clone());
        let layer_count = self.core.film.layers();
        Ok(match self.core.apply(&edit)? {
            Edited::Emitters(invalidation) => {
                let grown = matches!(
                    edit,
                    SceneEdit::Light { .. } | SceneEdit::AddLight(_) | SceneEdit::RemoveLight(_)
                ) && self.write_lights();
                match &edit {
                    // A new map, rotation or sampling changes the tables; a strength
                    // edit (nothing invalidated) only re-weights the layer.
                    SceneEdit::Environment(_) if invalidation != Invalidation::Nothing => {
                        self.reupload_environment(true);
                    }
                    SceneEdit::Background(_) => self.reupload_environment(false),
                    _ if self.core.film.layers() != layer_count || grown => {
                        // A light added or removed: the device's frame buffer follows,
                        // or the light table outgrew its room.
                        self.rebind();
                    }
                    _ => {}
                }
                invalidation
            }
            Edited::Camera | Edited::LightSamples => self.restart_all(),
            Edited::Resized => {
                self.resize_adaptive();
                self.rebind();
                self.restart_all()
            }
            Edited::Meshes => {
                // New UVs or material assignments may reach other clusters.
                if reachable_clusters(&self.core.scene) != self.scene_data.reach
                    && !self.all_clusters
                {
                    match self.rebuild_data() {
                        Ok(data) => self.scene_data = data,
                        Err(e) => {
                            if let Some(meshes) = meshes_before {
                                self.core.scene.meshes = meshes;
                            }
                            return Err(e);
                        }
                    }
                }
                self.core.bvh.update(&self.core.scene.meshes);
                self.rebind();
                self.restart_all()
            }
            Edited::Material { index, before } => {
                // The re-upload is checked against the device's limit first; the
                // material stays as it was if it would not fit.
                match self.rebuild_data() {
                    Ok(data) => self.scene_data = data,
                    Err(e) => {
                        self.core.scene.materials[index] = before;
                        return Err(e);
                    }
                }
                self.rebind();
                let after = &self.core.scene.materials[index];
                let bit = material_bit(index);
                let film = &mut self.core.film;
                let restarted = match EditedTexels::between(&before, after) {
                    Some(texels) => {
                        film.reset_where(|mask, b| mask & bit != 0 && texels.reaches(b))
                    }
                    None => film.reset_where(|mask, _| mask & bit != 0),
                };
                self.restarted(restarted)
            }
            Edited::Moving => match self.moving_mask() {
                // No material shades differently while moving: every sample stands.
                0 => Invalidation::Nothing,
                residual => {
                    let restarted = self.core.film.reset_where(|mask, _| mask & residual != 0);
                    self.restarted(restarted)
                }
            },
            Edited::Nothing => Invalidation::Nothing,
        })
    }
}
