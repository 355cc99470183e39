//! One compute entry point with an explicit bind-group layout (group 0, bindings in
//! order), storage buffers made from bytes, dispatches and read-backs. Explicit
//! layouts keep a binding that one entry point leaves unused from changing the others.

use std::sync::{Arc, Mutex};

use wgpu::util::DeviceExt;

use super::{GpuContext, GpuError};

/// The kind of each binding, in binding order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Slot {
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
    /// `var<uniform>`.
    Uniform,
}

pub(super) struct Kernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

/// Threads per workgroup of every kernel (`@workgroup_size(64)` in the shaders).
pub(super) const WORKGROUP: u32 = 64;

impl Kernel {
    pub fn new(ctx: &GpuContext, source: &str, entry: &str, slots: &[Slot]) -> Self {
        let module = ctx
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(entry),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let entries: Vec<wgpu::BindGroupLayoutEntry> = slots
            .iter()
            .enumerate()
            .map(|(i, slot)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: match slot {
                        Slot::Read => wgpu::BufferBindingType::Storage { read_only: true },
                        Slot::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                        Slot::Uniform => wgpu::BufferBindingType::Uniform,
                    },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(entry),
                entries: &entries,
            });
        let pipeline_layout = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(entry),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let pipeline = ctx
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            });
        Self { pipeline, layout }
    }

    /// The bind group of `buffers`, one per slot, in order.
    pub fn bind(&self, ctx: &GpuContext, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// Records a dispatch of `threads` invocations (rounded up to whole workgroups),
    /// in rows of at most `MAX_GROUPS_X` workgroups: a shader's invocation index is
    /// `id.x + id.y * num_workgroups.x * WORKGROUP`.
    pub fn record(&self, encoder: &mut wgpu::CommandEncoder, bind: &wgpu::BindGroup, threads: u32) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bind, &[]);
        let (x, y) = groups(threads);
        pass.dispatch_workgroups(x, y, 1);
    }
}

/// WebGPU's guaranteed limit of workgroups along one dimension.
pub(super) const MAX_GROUPS_X: u32 = 65_535;

/// The workgroup grid of `threads` invocations: (x, y) with x at most `MAX_GROUPS_X`.
pub(super) fn groups(threads: u32) -> (u32, u32) {
    let groups = threads.div_ceil(WORKGROUP).max(1);
    let x = groups.min(MAX_GROUPS_X);
    (x, groups.div_ceil(x))
}

/// A storage buffer holding `bytes` (at least 16 bytes: empty bindings are invalid),
/// readable by copies too.
pub(super) fn storage(ctx: &GpuContext, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    let mut padded;
    let contents = if bytes.len() < 16 || !bytes.len().is_multiple_of(4) {
        padded = bytes.to_vec();
        padded.resize(bytes.len().next_multiple_of(4).max(16), 0);
        &padded[..]
    } else {
        bytes
    };
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        })
}

/// A zeroed storage buffer of `size` bytes (at least 16).
pub(super) fn zeroed(ctx: &GpuContext, label: &str, size: u64) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.next_multiple_of(4).max(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A uniform buffer of `bytes`, rewritten per dispatch with `queue.write_buffer`.
pub(super) fn uniform(ctx: &GpuContext, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
}

/// Copies of `buffers` made by `encoder`'s end, read back after it is submitted.
pub(super) struct ReadBack {
    staging: Vec<(wgpu::Buffer, u64)>,
}

impl ReadBack {
    /// Records copies of the first `size` bytes of each buffer.
    pub fn record(
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: &[(&wgpu::Buffer, u64)],
    ) -> Self {
        let staging = buffers
            .iter()
            .map(|(b, size)| {
                let size = size.next_multiple_of(4).max(4);
                let s = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("read back"),
                    size,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                encoder.copy_buffer_to_buffer(b, 0, &s, 0, size);
                (s, size)
            })
            .collect();
        Self { staging }
    }

    /// Waits for the device and returns each buffer's bytes, or why the device
    /// could not give them (lost, or an error reported while it worked).
    pub fn finish(self, ctx: &GpuContext) -> Result<Vec<Vec<u8>>, GpuError> {
        let mapped = Arc::new(Mutex::new(vec![None; self.staging.len()]));
        for (i, (s, _)) in self.staging.iter().enumerate() {
            let mapped = Arc::clone(&mapped);
            s.map_async(wgpu::MapMode::Read, .., move |r| {
                if let Ok(mut m) = mapped.lock() {
                    m[i] = Some(r.map_err(|e| e.to_string()));
                }
            });
        }
        // A poll returns once the device's work is done, but the map callbacks run on
        // whichever thread polls: when another thread shares the device (the studio's
        // window and render thread, parallel tests), ours may still be running there
        // when our poll returns. So poll until every callback has reported.
        let started = std::time::Instant::now();
        let mapped = loop {
            ctx.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| ctx.lost(format!("waiting for the device: {e}")))?;
            if let Some(e) = ctx.failure() {
                return Err(e);
            }
            let m = mapped
                .lock()
                .map_err(|_| ctx.lost("a read-back callback panicked"))?
                .clone();
            if m.iter().all(Option::is_some) || started.elapsed() > MAP_TIMEOUT {
                break m;
            }
            std::thread::sleep(std::time::Duration::from_micros(100));
        };
        let mut out = Vec::with_capacity(self.staging.len());
        for ((s, _), m) in self.staging.into_iter().zip(mapped) {
            match m {
                Some(Ok(())) => {}
                Some(Err(e)) => return Err(ctx.lost(format!("reading a result back: {e}"))),
                None => return Err(ctx.lost("a read-back never completed")),
            }
            ctx.count_read_back(s.size());
            let bytes = s
                .get_mapped_range(..)
                .map_err(|e| ctx.lost(format!("reading a result back: {e}")))?
                .to_vec();
            s.unmap();
            out.push(bytes);
        }
        Ok(out)
    }
}

/// How long a read-back waits for its map callbacks after the device is idle before
/// it calls the device failed.
const MAP_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(30);

/// Submits `encoder` and reads back `buffers` (sizes in bytes).
pub(super) fn submit_and_read(
    ctx: &GpuContext,
    mut encoder: wgpu::CommandEncoder,
    buffers: &[(&wgpu::Buffer, u64)],
) -> Result<Vec<Vec<u8>>, GpuError> {
    let read = ReadBack::record(ctx, &mut encoder, buffers);
    ctx.queue.submit([encoder.finish()]);
    read.finish(ctx)
}

/// Waits until the device has done the work submitted so far.
pub(super) fn wait(ctx: &GpuContext) -> Result<(), GpuError> {
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| ctx.lost(format!("waiting for the device: {e}")))?;
    match ctx.failure() {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

pub(super) fn encoder(ctx: &GpuContext) -> wgpu::CommandEncoder {
    ctx.device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor::default())
}
