//! [`GpuJacobi`]: Chebyshev-accelerated Jacobi iterations on the GPU
//! (shader: `jacobi.wgsl`), after Wang 2015, "A Chebyshev semi-iterative
//! approach for accelerating projective and position-based dynamics", §4:
//!
//! `y = x_k + diag(A + D)⁻¹ (b - (A + D) x_k)`,
//! `x_{k+1} = ω_{k+1} (y - x_{k-1}) + x_{k-1}`,
//! `ω_1 = 1`, `ω_2 = 2 / (2 - ρ²)`, `ω_{k+1} = 4 / (4 - ρ² ω_k)`,
//!
//! with `ρ` the spectral radius of the Jacobi iteration matrix
//! `I - diag(A)⁻¹ A` (given, or estimated on the CPU by
//! [`estimate_jacobi_radius`]) and no under-relaxation (Wang's `γ = 1`).
//!
//! The matrix is uploaded once. A solve uploads `b`, `x` and the extra
//! diagonal, records [`GpuJacobiParams::check_every`] iterations per
//! submission followed by a residual reduction, and reads back only the
//! per-workgroup residual partials (a few floats) until the relative
//! residual `|b - (A + D) x| / |b|` is at most the tolerance or the
//! iteration budget is spent; `x` is read back once at the end. The residual
//! is evaluated in `f32` (relative residuals below about 1e-6 are not
//! resolved: such tolerances run to `max_iterations`).

// `!(a > b)` is deliberate: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{grid, grid_groups, to_u32, GpuContext, GpuError};
use crate::linalg::csr::CsrMatrix;
use crate::sim::backend::{check_jacobi_inputs, IterStats, JacobiSolve};
use crate::sim::SimError;

const SHADER: &str = include_str!("jacobi.wgsl");
const WG: u32 = 64;
const WG_REDUCE: u32 = 256;
/// Bytes of the `Params` uniform of `jacobi.wgsl`.
const PARAMS_SIZE: u64 = 16;
/// A relative residual above this ends the solve as diverged (a wrong `ρ` or
/// a matrix on which Jacobi does not converge).
const DIVERGED_RESIDUAL: f64 = 1e8;

/// Options of [`GpuJacobi`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpuJacobiParams {
    /// Spectral radius `ρ` of the Jacobi iteration matrix `I - diag(A)⁻¹ A`
    /// (dimensionless, in `[0, 1)`), which sets the Chebyshev weights (Wang
    /// 2015 Eq. 13). `None` (default): estimated by [`estimate_jacobi_radius`]
    /// at construction.
    pub rho: Option<f64>,
    /// Iterations per submission between residual readbacks (>= 1). Default
    /// 16: a readback stalls the device, and 16 iterations cost far more than
    /// one residual evaluation, while overshooting the tolerance by at most 15
    /// iterations.
    pub check_every: u32,
}

impl Default for GpuJacobiParams {
    fn default() -> Self {
        GpuJacobiParams {
            rho: None,
            check_every: 16,
        }
    }
}

/// Power iterations of [`estimate_jacobi_radius`].
const POWER_ITERATIONS: usize = 200;

/// Estimates the spectral radius `ρ` of the Jacobi iteration matrix
/// `I - diag(A)⁻¹ A` of a symmetric matrix with positive diagonal, on the
/// CPU in `f64`: power iteration (200 steps, fixed start vector: the result is
/// deterministic) on the similar symmetric matrix `I - D^{-1/2} A D^{-1/2}`.
/// Power iteration approaches `ρ` from below and Chebyshev weights built on
/// an underestimate can diverge, so the estimate `r` is returned raised to
/// `r + 0.1 (1 - r)` (erring on the safe, slower side; Wang 2015 §4.2 tunes
/// `ρ` by hand instead). An estimate `>= 1` (Jacobi itself diverges) is an
/// error.
pub fn estimate_jacobi_radius(a: &CsrMatrix) -> Result<f64, GpuError> {
    let n = a.n;
    let diag = a.diagonal();
    if let Some(r) = diag.iter().position(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(GpuError::Inconsistent(format!(
            "Jacobi needs a positive diagonal; row {r} has {}",
            diag[r]
        )));
    }
    if n == 0 {
        return Ok(0.0);
    }
    let inv_sqrt: Vec<f64> = diag.iter().map(|d| 1.0 / d.sqrt()).collect();
    // Deterministic, non-degenerate start (not orthogonal to smooth modes).
    let mut v: Vec<f64> = (0..n)
        .map(|i| 1.0 + 0.5 * ((i as f64) * 0.618_033_988_7).fract())
        .collect();
    let mut w = vec![0.0; n];
    let mut estimate = 0.0;
    for _ in 0..POWER_ITERATIONS {
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if !(norm > 0.0) || !norm.is_finite() {
            break;
        }
        for x in v.iter_mut() {
            *x /= norm;
        }
        for r in 0..n {
            let mut s = 0.0;
            for e in a.row_ptr[r]..a.row_ptr[r + 1] {
                let c = a.col[e];
                s += a.val[e] * inv_sqrt[c] * v[c];
            }
            w[r] = v[r] - inv_sqrt[r] * s;
        }
        estimate = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        std::mem::swap(&mut v, &mut w);
    }
    if !(estimate < 1.0) {
        return Err(GpuError::Inconsistent(format!(
            "the Jacobi iteration matrix has spectral radius about {estimate} >= 1: \
             Jacobi (and Chebyshev-Jacobi) would diverge"
        )));
    }
    Ok(estimate + 0.1 * (1.0 - estimate))
}

/// Most iteration slots of the parameter buffer (one uniform slot each).
const MAX_OMEGA_SLOTS: usize = 4096;

/// Number of distinct `ω_k` to store: until they settle to their limit
/// `2 / (1 + sqrt(1 - ρ²))` within 1e-9 (far below `f32` resolution), at
/// least 2, at most [`MAX_OMEGA_SLOTS`].
fn omega_slots(rho: f64) -> usize {
    let w = chebyshev_omegas(rho, MAX_OMEGA_SLOTS);
    let limit = 2.0 / (1.0 + (1.0 - rho * rho).max(0.0).sqrt());
    w.iter()
        .position(|x| (x - limit).abs() <= 1e-9)
        .map_or(MAX_OMEGA_SLOTS, |k| (k + 1).max(2))
}

/// The Chebyshev weight `ω_k` (1-based `k`) for spectral radius `rho`.
pub fn chebyshev_omegas(rho: f64, count: usize) -> Vec<f64> {
    let r2 = rho * rho;
    let mut out = Vec::with_capacity(count);
    for k in 1..=count {
        let w = match k {
            1 => 1.0,
            2 => 2.0 / (2.0 - r2),
            _ => 4.0 / (4.0 - r2 * out[k - 2]),
        };
        out.push(w);
    }
    out
}

/// Device buffers of [`GpuJacobi`] (bindings 1-8 of `jacobi.wgsl`).
struct Buffers {
    idx: wgpu::Buffer,
    val: wgpu::Buffer,
    diag: wgpu::Buffer,
    extra: wgpu::Buffer,
    rhs: wgpu::Buffer,
    xa: wgpu::Buffer,
    xb: wgpu::Buffer,
    partials: wgpu::Buffer,
}

/// The uniform buffer of `slots` parameter slots (slot 0 and 1: residual into
/// partials `[0, G)` and `[G, 2G)`; slot `1 + k`: iteration `k` with `ω_k`)
/// and the two bind groups (x_cur = xa, x_out = xb) and the swap.
#[allow(clippy::too_many_arguments)]
fn bind(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    bufs: &Buffers,
    rho: f64,
    n: usize,
    groups: u32,
    stride: u64,
    slots: usize,
) -> (wgpu::Buffer, [wgpu::BindGroup; 2]) {
    let stride = stride as usize;
    let mut bytes = vec![0u8; slots * stride];
    let omegas = chebyshev_omegas(rho, slots.saturating_sub(2));
    for s in 0..slots {
        let (omega, base) = match s {
            0 => (1.0f32, 0u32),
            1 => (1.0f32, groups),
            _ => (omegas[s - 2] as f32, 0),
        };
        let p = &mut bytes[s * stride..s * stride + PARAMS_SIZE as usize];
        p[0..4].copy_from_slice(&omega.to_le_bytes());
        p[4..8].copy_from_slice(&(n as u32).to_le_bytes());
        p[8..12].copy_from_slice(&base.to_le_bytes());
    }
    let params_buf = {
        use wgpu::util::DeviceExt;
        ctx.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("jacobi params"),
                contents: &bytes,
                usage: wgpu::BufferUsages::UNIFORM,
            })
    };
    let make = |cur: &wgpu::Buffer, out: &wgpu::Buffer| {
        let rest = [
            &bufs.idx,
            &bufs.val,
            &bufs.diag,
            &bufs.extra,
            &bufs.rhs,
            cur,
            out,
            &bufs.partials,
        ];
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &params_buf,
                offset: 0,
                size: std::num::NonZeroU64::new(PARAMS_SIZE),
            }),
        }];
        for (i, b) in rest.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry {
                binding: i as u32 + 1,
                resource: b.as_entire_binding(),
            });
        }
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("jacobi bind group"),
            layout,
            entries: &entries,
        })
    };
    let groups = [make(&bufs.xa, &bufs.xb), make(&bufs.xb, &bufs.xa)];
    (params_buf, groups)
}

/// The [`JacobiSolve`] of a fixed sparse SPD matrix on the GPU (`f32`).
pub struct GpuJacobi {
    ctx: GpuContext,
    n: usize,
    rho: f64,
    check_every: u32,
    cheb_pipeline: wgpu::ComputePipeline,
    residual_pipeline: wgpu::ComputePipeline,
    bufs: Buffers,
    staging: wgpu::Buffer,
    /// One `Params` slot per dispatch kind: slot 0 and 1 the residual into
    /// partials `[0, G)` and `[G, 2G)`, slot `1 + k` iteration `k` (the last
    /// slot serves all later iterations).
    /// Owned beside the bind groups that bind it (never read directly).
    _params_buf: wgpu::Buffer,
    param_stride: u64,
    param_slots: usize,
    /// Bind groups (x_cur = xa, x_out = xb) and (x_cur = xb, x_out = xa).
    bind_groups: [wgpu::BindGroup; 2],
    row_grid: (u32, u32),
    res_grid: (u32, u32),
    scratch: Vec<f32>,
}

impl std::fmt::Debug for GpuJacobi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuJacobi")
            .field("ctx", &self.ctx)
            .field("n", &self.n)
            .field("rho", &self.rho)
            .field("check_every", &self.check_every)
            .finish()
    }
}

fn to_f32_vec(v: &[f64], what: &str) -> Result<Vec<f32>, GpuError> {
    v.iter()
        .enumerate()
        .map(|(i, &x)| {
            let f = x as f32;
            if f.is_finite() {
                Ok(f)
            } else {
                Err(GpuError::Inconsistent(format!(
                    "{what} entry {i} ({x}) is not finite in f32"
                )))
            }
        })
        .collect()
}

impl GpuJacobi {
    /// Uploads `a` (square, both triangles, positive diagonal; rounded to
    /// `f32`) and builds the kernels. `params.rho = None` estimates `ρ`
    /// ([`estimate_jacobi_radius`]).
    pub fn new(
        ctx: &GpuContext,
        a: &CsrMatrix,
        params: GpuJacobiParams,
    ) -> Result<GpuJacobi, GpuError> {
        let n = a.n;
        let nnz = a.col.len();
        if a.row_ptr.len() != n + 1
            || a.val.len() != nnz
            || a.row_ptr.last() != Some(&nnz)
            || a.row_ptr.windows(2).any(|w| w[0] > w[1])
        {
            return Err(GpuError::Inconsistent(format!(
                "malformed CSR matrix: n {n}, {} row starts, {nnz} columns, {} values",
                a.row_ptr.len(),
                a.val.len()
            )));
        }
        if let Some(c) = a.col.iter().find(|&&c| c >= n) {
            return Err(GpuError::Inconsistent(format!(
                "CSR column {c} outside a {n} x {n} matrix"
            )));
        }
        if params.check_every == 0 {
            return Err(GpuError::Inconsistent("check_every must be >= 1".into()));
        }
        let rho = match params.rho {
            Some(r) if r.is_finite() && (0.0..1.0).contains(&r) => r,
            Some(r) => {
                return Err(GpuError::Inconsistent(format!(
                    "Chebyshev rho {r} must lie in [0, 1)"
                )))
            }
            None => estimate_jacobi_radius(a)?,
        };
        let diag = a.diagonal();
        if let Some(r) = diag.iter().position(|d| !(d.is_finite() && *d > 0.0)) {
            return Err(GpuError::Inconsistent(format!(
                "Jacobi needs a positive diagonal; row {r} has {}",
                diag[r]
            )));
        }
        to_u32(n + 1 + nnz, "CSR size")?;
        to_u32(3 * n, "3 x rows")?;
        let mut idx: Vec<u32> = Vec::with_capacity(n + 1 + nnz);
        idx.extend(a.row_ptr.iter().map(|&p| p as u32));
        idx.extend(a.col.iter().map(|&c| c as u32));
        let val = to_f32_vec(&a.val, "matrix")?;
        let diag32 = to_f32_vec(&diag, "diagonal")?;

        ctx.fits("the CSR indices", 4 * idx.len() as u64)?;
        ctx.fits("the solution", 12 * n as u64)?;
        let row_grid = grid(n, WG)?;
        let res_grid = grid(n, WG_REDUCE)?;
        let groups = grid_groups(res_grid);
        let none = wgpu::BufferUsages::empty();
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let copy_src = wgpu::BufferUsages::COPY_SRC;
        let idx_buf = ctx.storage_init("csr idx", bytemuck::cast_slice(&idx), none);
        let val_buf = ctx.storage_init("csr val", bytemuck::cast_slice(&val), none);
        let diag_buf = ctx.storage_init("diag", bytemuck::cast_slice(&diag32), none);
        let extra_buf = ctx.buffer("extra diag", 4 * n as u64, storage);
        let rhs_buf = ctx.buffer("rhs", 12 * n as u64, storage);
        let xa = ctx.buffer("x a", 12 * n as u64, storage | copy_src);
        let xb = ctx.buffer("x b", 12 * n as u64, storage | copy_src);
        let partials_buf = ctx.buffer("residual partials", 8 * groups as u64, storage | copy_src);
        let staging = ctx.buffer(
            "jacobi staging",
            (12 * n as u64).max(8 * groups as u64),
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );

        use wgpu::BufferBindingType as T;
        let ro = (T::Storage { read_only: true }, false);
        let rw = (T::Storage { read_only: false }, false);
        // Binding 0 (parameters) has a dynamic offset: one slot per dispatch.
        let (module, layout, pl) = ctx.kernel_layouts(
            "jacobi.wgsl",
            SHADER,
            &[(T::Uniform, true), ro, ro, ro, ro, ro, ro, rw, rw],
        );
        let cheb_pipeline = ctx.pipeline("cheb_kernel", &pl, &module, "cheb_kernel");
        let residual_pipeline = ctx.pipeline("residual_kernel", &pl, &module, "residual_kernel");
        let align = ctx.device.limits().min_uniform_buffer_offset_alignment as u64;
        let param_stride = PARAMS_SIZE.next_multiple_of(align.max(PARAMS_SIZE));
        let bufs = Buffers {
            idx: idx_buf,
            val: val_buf,
            diag: diag_buf,
            extra: extra_buf,
            rhs: rhs_buf,
            xa,
            xb,
            partials: partials_buf,
        };
        let groups32 = to_u32(groups, "workgroups")?;
        let slots = 2 + omega_slots(rho);
        let (params_buf, bind_groups) =
            bind(ctx, &layout, &bufs, rho, n, groups32, param_stride, slots);
        let solver = GpuJacobi {
            ctx: ctx.clone(),
            n,
            rho,
            check_every: params.check_every,
            cheb_pipeline,
            residual_pipeline,
            bufs,
            staging,
            _params_buf: params_buf,
            param_stride,
            param_slots: slots,
            bind_groups,
            row_grid,
            res_grid,
            scratch: Vec::new(),
        };
        ctx.check("creating the Jacobi kernels")?;
        Ok(solver)
    }

    /// The `ρ` the Chebyshev weights use.
    pub fn rho(&self) -> f64 {
        self.rho
    }

    /// The context this solver runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Dynamic offset of the parameter slot `slot`; iterations past the last
    /// slot reuse it (`ω_k` has converged to `f32` precision there).
    fn offset(&self, slot: usize) -> u32 {
        (slot.min(self.param_slots - 1) as u64 * self.param_stride) as u32
    }

    /// Reads back `n x 3` values of `buf`.
    fn read_x(&self, buf: &wgpu::Buffer) -> Result<Vec<f32>, GpuError> {
        let size = 12 * self.n as u64;
        let mut encoder = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("jacobi read x"),
            });
        if size > 0 {
            encoder.copy_buffer_to_buffer(buf, 0, &self.staging, 0, size);
        }
        let bytes = self
            .ctx
            .submit_and_read(encoder, &self.staging, size, "Jacobi result")?;
        let mut v: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
        v.truncate(3 * self.n);
        Ok(v)
    }

    fn run(
        &mut self,
        b: &[f64],
        extra_diag: Option<&[f64]>,
        x: &mut [f64],
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<IterStats, SimError> {
        let n = self.n;
        check_jacobi_inputs("GPU Jacobi", n, b, extra_diag, x)?;
        if !(tolerance >= 0.0) {
            return Err(SimError::Inconsistent(format!(
                "Jacobi tolerance {tolerance} must be >= 0"
            )));
        }
        let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !b_norm.is_finite() {
            return Err(SimError::Inconsistent(
                "Jacobi right-hand side is not finite".into(),
            ));
        }
        if b_norm == 0.0 {
            // (A + D) is SPD: the solution is 0 and the relative residual 0 by
            // the trait's convention.
            x.fill(0.0);
            return Ok(IterStats {
                iterations: 0,
                relative_residual: 0.0,
            });
        }
        let ctx = self.ctx.clone();
        ctx.queue.write_buffer(
            &self.bufs.rhs,
            0,
            bytemuck::cast_slice(&to_f32_vec(b, "rhs")?),
        );
        let x32 = to_f32_vec(x, "initial guess")?;
        ctx.queue
            .write_buffer(&self.bufs.xa, 0, bytemuck::cast_slice(&x32));
        ctx.queue
            .write_buffer(&self.bufs.xb, 0, bytemuck::cast_slice(&x32));
        self.scratch.clear();
        match extra_diag {
            Some(d) => self.scratch.extend(d.iter().map(|&v| v as f32)),
            None => self.scratch.resize(n, 0.0),
        }
        ctx.queue
            .write_buffer(&self.bufs.extra, 0, bytemuck::cast_slice(&self.scratch));

        let groups = grid_groups(self.res_grid);
        // Which buffer holds the newest iterate: 0 = xa, 1 = xb.
        let mut cur = 0usize;
        let mut iterations = 0u32;
        let mut first = true;
        let residual = loop {
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("chebyshev jacobi"),
                });
            let chunk = self.check_every.min(max_iterations - iterations);
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("chebyshev jacobi"),
                    timestamp_writes: None,
                });
                if first {
                    pass.set_pipeline(&self.residual_pipeline);
                    pass.set_bind_group(0, &self.bind_groups[cur], &[self.offset(0)]);
                    pass.dispatch_workgroups(self.res_grid.0, self.res_grid.1, 1);
                }
                pass.set_pipeline(&self.cheb_pipeline);
                for j in 0..chunk {
                    let k = (iterations + j + 1) as usize;
                    pass.set_bind_group(0, &self.bind_groups[cur], &[self.offset(1 + k)]);
                    pass.dispatch_workgroups(self.row_grid.0, self.row_grid.1, 1);
                    cur = 1 - cur;
                }
                pass.set_pipeline(&self.residual_pipeline);
                pass.set_bind_group(0, &self.bind_groups[cur], &[self.offset(1)]);
                pass.dispatch_workgroups(self.res_grid.0, self.res_grid.1, 1);
            }
            encoder.copy_buffer_to_buffer(
                &self.bufs.partials,
                0,
                &self.staging,
                0,
                8 * groups as u64,
            );
            let bytes =
                ctx.submit_and_read(encoder, &self.staging, 8 * groups as u64, "Jacobi residual")?;
            let parts: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
            let norm =
                |p: &[f32]| p.iter().map(|&v| v as f64).sum::<f64>().max(0.0).sqrt() / b_norm;
            if first {
                let r0 = norm(&parts[..groups]);
                if r0 <= tolerance {
                    // The initial guess is good enough: x is left as given.
                    return Ok(IterStats {
                        iterations: 0,
                        relative_residual: r0,
                    });
                }
            }
            first = false;
            iterations += chunk;
            let r = norm(&parts[groups..2 * groups]);
            if !(r <= DIVERGED_RESIDUAL) {
                let xs = self.read_x(if cur == 0 {
                    &self.bufs.xa
                } else {
                    &self.bufs.xb
                })?;
                let node = worst_node(&xs);
                return Err(SimError::Diverged {
                    // The solver does not know the time step; the time loop
                    // that calls it reports the step of its own errors.
                    step: 0,
                    node,
                    reason: format!(
                        "GPU Chebyshev-Jacobi diverged: relative residual {r} after {iterations} \
                         iterations (rho {})",
                        self.rho
                    ),
                });
            }
            if r <= tolerance || iterations >= max_iterations {
                break r;
            }
        };
        let xs = self.read_x(if cur == 0 {
            &self.bufs.xa
        } else {
            &self.bufs.xb
        })?;
        for (o, v) in x.iter_mut().zip(&xs) {
            *o = *v as f64;
        }
        Ok(IterStats {
            iterations,
            relative_residual: residual,
        })
    }
}

/// The node with a non-finite or the largest coordinate.
fn worst_node(x: &[f32]) -> usize {
    let mut worst = (0usize, -1.0f32);
    for (i, p) in x.chunks_exact(3).enumerate() {
        let m = p.iter().fold(0.0f32, |m, v| {
            if v.is_finite() {
                m.max(v.abs())
            } else {
                f32::INFINITY
            }
        });
        if m > worst.1 {
            worst = (i, m);
            if m == f32::INFINITY {
                break;
            }
        }
    }
    worst.0
}

impl JacobiSolve for GpuJacobi {
    fn solve(
        &mut self,
        b: &[f64],
        extra_diag: Option<&[f64]>,
        x: &mut [f64],
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<IterStats, SimError> {
        self.run(b, extra_diag, x, tolerance, max_iterations)
    }

    fn name(&self) -> &'static str {
        "gpu"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn omegas_follow_wang() {
        let w = chebyshev_omegas(0.9, 4);
        assert_eq!(w[0], 1.0);
        assert!((w[1] - 2.0 / (2.0 - 0.81)).abs() < 1e-15);
        assert!((w[2] - 4.0 / (4.0 - 0.81 * w[1])).abs() < 1e-15);
        // The weights converge to 2 / (1 + sqrt(1 - rho²)).
        let w = chebyshev_omegas(0.9, 200);
        assert!((w[199] - 2.0 / (1.0 + (1.0f64 - 0.81).sqrt())).abs() < 1e-9);
    }

    #[test]
    fn omega_slots_stop_when_the_weights_settle() {
        assert_eq!(omega_slots(0.0), 2);
        let k = omega_slots(0.99);
        assert!(k > 10 && k < MAX_OMEGA_SLOTS, "{k}");
        let w = chebyshev_omegas(0.99, MAX_OMEGA_SLOTS);
        assert!((w[k - 1] - w[MAX_OMEGA_SLOTS - 1]).abs() < 1e-8);
        assert!(omega_slots(0.999_999) <= MAX_OMEGA_SLOTS);
    }

    #[test]
    fn radius_estimate_of_a_1d_laplacian() {
        // tridiag(-1, 2 + m, -1): Jacobi radius 2 cos(pi / (n + 1)) / (2 + m).
        let n = 50;
        let m = 0.1;
        let mut t = Vec::new();
        for i in 0..n {
            t.push((i, i, 2.0 + m));
            if i + 1 < n {
                t.push((i, i + 1, -1.0));
                t.push((i + 1, i, -1.0));
            }
        }
        let a = CsrMatrix::from_triplets(n, &t).unwrap();
        let exact = 2.0 * (std::f64::consts::PI / (n as f64 + 1.0)).cos() / (2.0 + m);
        let est = estimate_jacobi_radius(&a).unwrap();
        assert!(est >= exact * 0.999 && est < 1.0, "{est} vs {exact}");
        // A matrix on which Jacobi diverges is refused.
        let bad = CsrMatrix::from_triplets(
            3,
            &[
                (0, 0, 1.0),
                (1, 1, 1.0),
                (2, 2, 1.0),
                (0, 1, 0.9),
                (1, 0, 0.9),
                (0, 2, 0.9),
                (2, 0, 0.9),
                (1, 2, 0.9),
                (2, 1, 0.9),
            ],
        )
        .unwrap();
        assert!(estimate_jacobi_radius(&bad).is_err());
    }
}
