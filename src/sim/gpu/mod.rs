//! GPU backend of the PD kernels (wgpu, Vulkan, WGSL compute shaders, `f32`
//! on the device): [`GpuElasticRhs`] implements [`super::backend::ElasticRhs`]
//! (the local step of VH §7.1, Eq. 26, fused with the elastic sums of the
//! global right-hand side, Eq. 28) and [`GpuJacobi`] implements
//! [`super::backend::JacobiSolve`] (Chebyshev-accelerated Jacobi, Wang 2015);
//! [`GpuNodeProjector`] projects nodes out of planes and spheres (the contact
//! projections of VH §8.5) with [`project_point`] as its CPU twin.
//!
//! Any Vulkan adapter is accepted, including the CPU driver lavapipe (Mesa),
//! which is what CI runs the tests on. [`GpuContext::new`] reports a machine
//! without a Vulkan adapter as [`GpuError::Unavailable`], distinct from real
//! failures, so callers can fall back to the CPU backend.
//!
//! # Precision
//! Everything on the device is `f32` (unit roundoff 6e-8); inputs are rounded
//! from `f64` on upload and results widened on download.
//!
//! * The signed SVD (McAdams et al. 2011 style) runs 8 cyclic Jacobi sweeps on
//!   `FᵀF` for `V`, then a Givens QR of `F V` for `U` and the signed singular
//!   values, which are therefore accurate to about `ε_f32 s1` in absolute
//!   terms even for flat or inverted tets (no division by small singular
//!   values, no NaN for `F = 0`).
//! * Measured against the `f64` CPU reference (tests/sim_gpu.rs, lavapipe):
//!   the elastic right-hand side and the energy agree to a relative error of
//!   about 3e-7 on 162-tet blocks with random deformations including
//!   inverted, flattened and floor-clamped tets, 2e-6 on a 79K-tet block; 40
//!   Chebyshev-Jacobi iterations agree with the `f64` iteration to 2e-7.
//! * The energy of a tet is computed from the singular values
//!   (`|F - R|² = Σ (s_i - 1)²`, `|F - V|² = Σ (s_i - d_i)²`), so near the
//!   rest state its absolute error is about `ε_f32 |F|` per term instead of
//!   the cancellation of `F - R` in matrix form.
//! * Where the projections themselves are ill-conditioned (the rotation of a
//!   tet collapsed to a line or a point, `s2 + s3 ≈ 0`) the GPU result is
//!   finite but may differ from the CPU one, as any two implementations
//!   would.
//! * The Jacobi residual is evaluated in `f32`: relative residuals below
//!   about 1e-6 are not resolved.
//!
//! Energies and residual norms are reduced in fixed tree order on the device
//! and the per-workgroup partials summed in `f64` on the host, and every node
//! sums its tets in tet order (no atomics), so results are bit-identical from
//! run to run on a given device.
//!
//! Pure: no files, no printing, no environment (the Vulkan loader itself
//! honours its `VK_*` variables, e.g. `VK_ICD_FILENAMES` to pick a driver).

mod elastic;
mod jacobi;
mod project;

pub use elastic::GpuElasticRhs;
pub use jacobi::{chebyshev_omegas, estimate_jacobi_radius, GpuJacobi, GpuJacobiParams};
pub use project::{project_point, Collider, Colliders, GpuNodeProjector};

use std::sync::{mpsc, Arc, Mutex};

use super::SimError;

/// Errors of the GPU backend.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GpuError {
    /// No usable Vulkan adapter on this machine (no driver, no loader, no
    /// device): not a bug, the caller may fall back to the CPU backend.
    #[error("no GPU available: {0}")]
    Unavailable(String),
    /// The device failed (validation error, out of memory, lost device, a
    /// failed buffer mapping).
    #[error("GPU failure: {0}")]
    Device(String),
    /// Inputs that do not fit (sizes beyond the device limits, lengths,
    /// matrices the method cannot handle).
    #[error("inconsistent GPU inputs: {0}")]
    Inconsistent(String),
}

impl From<GpuError> for SimError {
    fn from(e: GpuError) -> SimError {
        // SimError has no backend variant; the message keeps the cause.
        SimError::Inconsistent(format!("GPU backend: {e}"))
    }
}

/// A wgpu device and queue on a Vulkan adapter, shared by the GPU kernels
/// (cheap to clone: wgpu handles are reference counted).
#[derive(Clone)]
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    /// Errors the device reported asynchronously (validation, out of memory);
    /// taken and turned into [`GpuError::Device`] after every wait.
    errors: Arc<Mutex<Vec<String>>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.adapter_name())
            .finish()
    }
}

/// The adapter [`GpuContext::new`] opens, its information and limits, once
/// it is known to offer what the kernels need.
fn open_adapter() -> Result<(wgpu::Adapter, wgpu::AdapterInfo, wgpu::Limits), GpuError> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        apply_limit_buckets: false,
    }))
    .map_err(|e| GpuError::Unavailable(format!("no Vulkan adapter: {e}")))?;
    let info = adapter.get_info();
    // The adapter's own limits: the kernels need 8 storage buffers per
    // stage (the WebGPU default) and large storage bindings for big meshes.
    let limits = adapter.limits();
    if limits.max_storage_buffers_per_shader_stage < 8 {
        return Err(GpuError::Unavailable(format!(
            "adapter {} offers {} storage buffers per shader stage; 8 are needed",
            info.name, limits.max_storage_buffers_per_shader_stage
        )));
    }
    Ok((adapter, info, limits))
}

/// Whether [`GpuContext::new`] would open a hardware adapter (not a CPU
/// implementation such as lavapipe), without creating a device. Probed once
/// per process and remembered: opening a Vulkan instance and enumerating
/// its adapters costs 0.05-0.3 s, which `--backend auto` used to pay (and
/// then create a device to throw away) before every CPU run.
pub fn hardware_adapter_available() -> bool {
    static PROBE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *PROBE.get_or_init(|| {
        open_adapter().is_ok_and(|(_, info, _)| info.device_type != wgpu::DeviceType::Cpu)
    })
}

impl GpuContext {
    /// Opens the first high-performance Vulkan adapter (a discrete GPU when
    /// there is one, else any, including lavapipe), blocking on wgpu's futures
    /// with `pollster`. No adapter: [`GpuError::Unavailable`].
    pub fn new() -> Result<GpuContext, GpuError> {
        let (adapter, info, limits) = open_adapter()?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("knitvox-pd"),
            required_features: wgpu::Features::empty(),
            required_limits: limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device(format!("request_device on {}: {e}", info.name)))?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        Ok(GpuContext {
            device,
            queue,
            info,
            errors,
        })
    }

    /// The adapter's name (e.g. "llvmpipe (LLVM 15.0.6, 256 bits)").
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// Full adapter information (vendor, device type, driver) for statistics.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// Whether the adapter is a CPU implementation (lavapipe, SwiftShader):
    /// timings on it say nothing about GPU speed.
    pub fn is_cpu_adapter(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Turns asynchronously reported device errors into an error.
    pub(crate) fn check(&self, what: &str) -> Result<(), GpuError> {
        let mut v = self
            .errors
            .lock()
            .map_err(|_| GpuError::Device(format!("{what}: error log poisoned")))?;
        if v.is_empty() {
            return Ok(());
        }
        let msg = v.join("; ");
        v.clear();
        Err(GpuError::Device(format!("{what}: {msg}")))
    }

    /// Checks that storage buffers of `bytes` bytes fit the device limits,
    /// naming `what` (a mesh or matrix too large for this device is an input
    /// error, not a device failure).
    pub(crate) fn fits(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        let l = self.device.limits();
        let max = l.max_storage_buffer_binding_size.min(l.max_buffer_size);
        if bytes > max {
            return Err(GpuError::Inconsistent(format!(
                "{what} needs a {bytes}-byte buffer; {} allows {max}",
                self.info.name
            )));
        }
        Ok(())
    }

    /// A storage buffer holding `data` (at least 4 bytes: wgpu rejects empty
    /// bindings).
    pub(crate) fn storage_init(
        &self,
        label: &str,
        data: &[u8],
        extra: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        let padded;
        let contents = if data.len() < 4 {
            padded = [0u8; 4];
            &padded[..]
        } else {
            data
        };
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
            })
    }

    /// An uninitialized (zeroed) buffer of `size` bytes (at least 4).
    pub(crate) fn buffer(&self, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(4).next_multiple_of(4),
            usage,
            mapped_at_creation: false,
        })
    }

    /// Submits `encoder`, waits, and maps the first `size` bytes of the
    /// `MAP_READ` buffer `staging` (which the encoder filled), returning them.
    pub(crate) fn submit_and_read(
        &self,
        encoder: wgpu::CommandEncoder,
        staging: &wgpu::Buffer,
        size: u64,
        what: &str,
    ) -> Result<Vec<u8>, GpuError> {
        self.queue.submit(Some(encoder.finish()));
        let size = size.max(4);
        let slice = staging.slice(..size);
        let (tx, rx) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Device(format!("{what}: waiting for the device: {e}")))?;
        self.check(what)?;
        match rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(GpuError::Device(format!("{what}: mapping: {e}"))),
            Err(_) => return Err(GpuError::Device(format!("{what}: mapping never completed"))),
        }
        let bytes = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Device(format!("{what}: mapped range: {e}")))?;
            view.to_vec()
        };
        staging.unmap();
        Ok(bytes)
    }

    /// The shader module of the WGSL `source`, the bind group layout of its
    /// buffer `bindings` (binding `i` = entry `i`: type and whether it has a
    /// dynamic offset) and the pipeline layout with that one group: what
    /// every kernel file needs before [`Self::pipeline`].
    pub(crate) fn kernel_layouts(
        &self,
        label: &str,
        source: &str,
        bindings: &[(wgpu::BufferBindingType, bool)],
    ) -> (
        wgpu::ShaderModule,
        wgpu::BindGroupLayout,
        wgpu::PipelineLayout,
    ) {
        let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
            .iter()
            .enumerate()
            .map(|(i, &(ty, dynamic))| layout_entry(i as u32, ty, dynamic))
            .collect();
        let layout = self
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(&format!("{label} layout")),
                entries: &entries,
            });
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let pipeline_layout = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(&format!("{label} pipeline layout")),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        (module, layout, pipeline_layout)
    }

    /// A bind group binding `buffers[i]` whole at binding `i`.
    pub(crate) fn bind_buffers(
        &self,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        })
    }

    /// A compute pipeline for `entry` of `module` with `layout`.
    pub(crate) fn pipeline(
        &self,
        label: &str,
        layout: &wgpu::PipelineLayout,
        module: &wgpu::ShaderModule,
        entry: &str,
    ) -> wgpu::ComputePipeline {
        self.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
    }
}

/// Bind group layout entry of a compute-stage buffer binding.
pub(crate) fn layout_entry(
    binding: u32,
    ty: wgpu::BufferBindingType,
    dynamic: bool,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: dynamic,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Largest workgroup count per dispatch dimension (WebGPU default limit).
const MAX_GROUPS_PER_DIM: u32 = 65_535;

/// Workgroup grid `(x, y)` covering `items` items with `wg` threads per
/// group; the shaders linearize `gid.x + gid.y * num_workgroups.x * wg`.
pub(crate) fn grid(items: usize, wg: u32) -> Result<(u32, u32), GpuError> {
    let groups = items.div_ceil(wg as usize).max(1);
    let x = groups.min(MAX_GROUPS_PER_DIM as usize);
    let y = groups.div_ceil(x);
    if y > MAX_GROUPS_PER_DIM as usize {
        return Err(GpuError::Inconsistent(format!(
            "{items} items exceed the dispatch limits"
        )));
    }
    Ok((x as u32, y as u32))
}

/// Number of workgroups [`grid`] launches (the size of partial-sum arrays).
pub(crate) fn grid_groups(g: (u32, u32)) -> usize {
    g.0 as usize * g.1 as usize
}

/// Converts a host index to the device's `u32`.
pub(crate) fn to_u32(v: usize, what: &str) -> Result<u32, GpuError> {
    u32::try_from(v).map_err(|_| GpuError::Inconsistent(format!("{what} {v} exceeds u32")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_covers_items() {
        assert_eq!(grid(0, 64).unwrap(), (1, 1));
        assert_eq!(grid(64, 64).unwrap(), (1, 1));
        assert_eq!(grid(65, 64).unwrap(), (2, 1));
        let g = grid(64 * 70_000, 64).unwrap();
        assert!(grid_groups(g) >= 70_000 && g.0 <= MAX_GROUPS_PER_DIM);
        assert!(grid(usize::MAX / 2, 64).is_err());
    }

    #[test]
    fn kernels_can_move_between_threads() {
        // The time loop may own its backends from a worker thread.
        fn send_sync<T: Send + Sync>() {}
        send_sync::<GpuContext>();
        send_sync::<GpuElasticRhs>();
        send_sync::<GpuJacobi>();
        send_sync::<GpuNodeProjector>();
    }

    #[test]
    fn gpu_error_maps_to_sim_error() {
        let e: SimError = GpuError::Device("lost".into()).into();
        assert!(e.to_string().contains("GPU backend") && e.to_string().contains("lost"));
    }
}
