//! The device side of a prepared scene: geometry, data, parameters, counters and the
//! environment, bound to the integrator's kernel.

use super::*;

/// The device side of a prepared scene.
pub(super) struct Resources {
    pub(super) geometry: GeometryBuffers,
    pub(super) data: wgpu::Buffer,
    pub(super) data_bytes: DataBytes,
    pub(super) params: wgpu::Buffer,
    pub(super) counters: wgpu::Buffer,
    pub(super) env: wgpu::Buffer,
    pub(super) bind: wgpu::BindGroup,
}

impl Resources {
    pub(super) fn upload(
        ctx: &GpuContext,
        kernel: &Kernel,
        bvh: &SceneBvh,
        scene: &Scene,
        (data, env_words): (&SceneData, &[u32]),
        film: &DeviceFilm,
    ) -> Self {
        let geometry = GeometryBuffers::upload(ctx, bvh, &scene.meshes);
        let data_buf = kernel::storage(ctx, "data", bytemuck::cast_slice(&data.words.words));
        let params = kernel::uniform(ctx, "params", bytemuck::bytes_of(&Params::default()));
        let counters = kernel::zeroed(ctx, "counters", COUNTERS as u64 * 4);
        let env = kernel::storage(ctx, "environment", bytemuck::cast_slice(env_words));
        let bind = kernel.bind(
            ctx,
            &[
                &params,
                &geometry.nodes,
                &geometry.tris,
                &geometry.shade,
                &data_buf,
                &film.frame,
                &film.aux,
                &counters,
                &env,
            ],
        );
        Self {
            geometry,
            data: data_buf,
            data_bytes: data.words.bytes,
            params,
            counters,
            env,
            bind,
        }
    }
}
