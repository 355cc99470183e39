//! A GPU mode's image as it stays on the device (`DeviceImage`), and the texture a
//! window shows it in (`DisplayTexture`, shaders/display.wgsl): when the window draws
//! with the mode's device, a frame reaches the screen without a copy through the
//! host; the host reads an image back only when it needs one (saving, comparing,
//! the denoiser's first frames).

use std::sync::{Arc, OnceLock};

use bytemuck::{Pod, Zeroable};

use super::kernel;
use super::{GpuContext, GpuError, shaders};
use meso_materials::image::{Image, exposure_scale};
use meso_render::{ImageOnDevice, ModeError};

/// A resolved image in a device buffer of its own (linear RGB, one `vec4<f32>` per
/// pixel): one frame's picture, which later frames do not change. Cloning shares it.
#[derive(Clone)]
pub struct DeviceImage {
    ctx: GpuContext,
    buffer: wgpu::Buffer,
    width: u32,
    height: u32,
    /// The image once read back (read at most once).
    host: Arc<OnceLock<Result<Arc<Image>, GpuError>>>,
}

impl std::fmt::Debug for DeviceImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceImage")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish()
    }
}

impl DeviceImage {
    pub(super) fn new(ctx: GpuContext, buffer: wgpu::Buffer, width: u32, height: u32) -> Self {
        Self {
            ctx,
            buffer,
            width,
            height,
            host: Arc::default(),
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// The device it is on.
    pub(super) fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The buffer holding it (one `vec4<f32>` per pixel), for kernels that read it.
    pub(super) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The image on the host: read back the first time it is asked for.
    pub fn read(&self) -> Result<Arc<Image>, GpuError> {
        self.host
            .get_or_init(|| {
                let size = u64::from(self.width) * u64::from(self.height) * 16;
                let enc = kernel::encoder(&self.ctx);
                let bytes = kernel::submit_and_read(&self.ctx, enc, &[(&self.buffer, size)])?;
                let texels: &[[f32; 4]] = bytemuck::cast_slice(&bytes[0]);
                let mut img = Image::new(self.width, self.height);
                for (p, t) in img.pixels_mut().iter_mut().zip(texels) {
                    *p = [t[0], t[1], t[2]];
                }
                Ok(Arc::new(img))
            })
            .clone()
    }

    /// Encodes the image into `target` after `exposure_stops`, as
    /// `image::to_srgb8` does, on the device (nothing is read back).
    pub fn show_in(&self, target: &mut DisplayTexture, exposure_stops: f64) {
        target.fit(self.width, self.height);
        let params = DisplayParams {
            width: self.width,
            height: self.height,
            scale: exposure_scale(exposure_stops) as f32,
            pad: 0,
        };
        self.ctx
            .queue
            .write_buffer(&target.params, 0, bytemuck::bytes_of(&params));
        let bind = self
            .ctx
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("display"),
                layout: &target.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: target.params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(&target.view),
                    },
                ],
            });
        let mut enc = kernel::encoder(&self.ctx);
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(&target.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(self.width.div_ceil(8), self.height.div_ceil(8), 1);
        }
        self.ctx.queue.submit([enc.finish()]);
    }
}

impl ImageOnDevice for DeviceImage {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn read(&self) -> Result<Arc<Image>, ModeError> {
        DeviceImage::read(self).map_err(|e| ModeError::DeviceFailed(e.to_string()))
    }

    fn wait(&self) -> Result<(), ModeError> {
        self.ctx
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| ModeError::DeviceFailed(format!("waiting for the device: {e}")))
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// The uniform block of `shaders/display.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DisplayParams {
    width: u32,
    height: u32,
    scale: f32,
    pad: u32,
}

/// A texture on a window's device that `DeviceImage::show_in` writes (8-bit sRGB
/// codes in `Rgba8Unorm`, what egui 0.37's renderer asks of a native texture: it
/// samples gamma-encoded values) and a window samples through `view`. It follows the
/// size of the images shown in it; `generation` changes when the texture is made anew.
pub struct DisplayTexture {
    ctx: GpuContext,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    generation: u64,
}

impl DisplayTexture {
    const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

    /// A texture on `ctx`'s device, for the images of modes on that context.
    pub fn new(ctx: &GpuContext) -> Self {
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("display"),
            source: wgpu::ShaderSource::Wgsl(shaders::module(&[shaders::DISPLAY]).into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("display"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: Self::FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("display"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("display"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("show"),
            compilation_options: Default::default(),
            cache: None,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("display params"),
            size: std::mem::size_of::<DisplayParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let (texture, view) = Self::make(device, 1, 1);
        Self {
            ctx: ctx.clone(),
            pipeline,
            layout,
            params,
            texture,
            view,
            generation: 0,
        }
    }

    fn make(device: &wgpu::Device, width: u32, height: u32) -> (wgpu::Texture, wgpu::TextureView) {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("viewport"),
            size: wgpu::Extent3d {
                width: width.max(1),
                height: height.max(1),
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: Self::FORMAT,
            usage: wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        (texture, view)
    }

    /// Encodes `image` into the texture after `exposure_stops` (`DeviceImage::show_in`)
    /// when it is an image of this texture's device; false (nothing done) otherwise.
    pub fn show(&mut self, image: &dyn ImageOnDevice, exposure_stops: f64) -> bool {
        match image.as_any().downcast_ref::<DeviceImage>() {
            Some(d) if d.ctx.same_device(&self.ctx) => {
                d.show_in(self, exposure_stops);
                true
            }
            _ => false,
        }
    }

    /// Makes the texture anew when the images shown change size.
    fn fit(&mut self, width: u32, height: u32) {
        let size = self.texture.size();
        if (size.width, size.height) != (width.max(1), height.max(1)) {
            (self.texture, self.view) = Self::make(&self.ctx.device, width, height);
            self.generation += 1;
        }
    }

    /// The view a window samples (and the display pass writes).
    pub fn view(&self) -> &wgpu::TextureView {
        &self.view
    }

    /// Changes whenever `view` is a new texture (a window registers it again).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    pub fn size(&self) -> (u32, u32) {
        let s = self.texture.size();
        (s.width, s.height)
    }

    /// The texture's 8-bit codes, read back (tests; the window never reads it).
    pub fn read_codes(&self) -> Result<Vec<[u8; 3]>, GpuError> {
        let ctx = &self.ctx;
        let (w, h) = self.size();
        let row = (w * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let staging = kernel::zeroed(ctx, "display read", u64::from(row) * u64::from(h));
        let mut enc = kernel::encoder(ctx);
        enc.copy_texture_to_buffer(
            self.texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(h),
                },
            },
            self.texture.size(),
        );
        let size = u64::from(row) * u64::from(h);
        let bytes = kernel::submit_and_read(ctx, enc, &[(&staging, size)])?;
        let mut codes = Vec::with_capacity((w * h) as usize);
        for y in 0..h as usize {
            let line = &bytes[0][y * row as usize..];
            codes.extend((0..w as usize).map(|x| [line[4 * x], line[4 * x + 1], line[4 * x + 2]]));
        }
        Ok(codes)
    }
}
