//! What must fit in one buffer of the device (the film's sums, the data and
//! environment words), refused with the adapter's limit before anything is
//! allocated; the device film as the progressive skeleton resizes it.

use super::*;

/// Why the film's largest buffer at `width` x `height` (its sums, or an adaptive
/// film's `aux` words) would not fit in one buffer of the device (`None` if it fits):
/// refused before anything is allocated.
pub(super) fn device_size_problem(
    ctx: &GpuContext,
    (width, height): (u32, u32),
    layers: usize,
    aux_words: usize,
) -> Option<String> {
    let bytes = film::largest_buffer(width, height, layers, aux_words);
    too_large(
        ctx,
        bytes,
        &format!("{width} x {height} with {layers} film layers needs"),
    )
}

/// Why one buffer of `bytes` bytes would not fit on the device (`None` if it fits),
/// the sentence begun by `what`.
fn too_large(ctx: &GpuContext, bytes: u64, what: &str) -> Option<String> {
    let limits = ctx.limits();
    let limit = limits
        .max_buffer_size
        .min(limits.max_storage_buffer_binding_size);
    (bytes > limit).then(|| {
        format!(
            "{what} a {bytes}-byte buffer on the GPU; `{}` allows {limit}",
            ctx.adapter_name()
        )
    })
}

impl ProgressiveFilm for DeviceFilm {
    fn width(&self) -> u32 {
        DeviceFilm::width(self)
    }
    fn height(&self) -> u32 {
        DeviceFilm::height(self)
    }
    fn resize_problem(&self, width: u32, height: u32) -> Result<(), EditError> {
        match device_size_problem(
            self.context(),
            (width, height),
            self.layers(),
            self.aux_words(),
        ) {
            Some(p) => Err(EditError::Size(p)),
            None => Ok(()),
        }
    }
    fn resize(&mut self, width: u32, height: u32) {
        DeviceFilm::resize(self, width, height);
    }
}

pub(super) const ENVIRONMENT_WORDS: &str =
    "the [environment] map with its sampling tables and the [background] image";
pub(super) const MATERIAL_WORDS_NAME: &str =
    "the materials (SPMM packs, MERL and `btf` tables) and lights";

/// Why `words` words of `what` would not fit in one buffer of the device (`None` if
/// they fit).
pub(super) fn words_size_problem(ctx: &GpuContext, what: &str, words: usize) -> Option<String> {
    too_large(ctx, words as u64 * 4, &format!("{what} need"))
}
