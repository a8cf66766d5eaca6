//! [`GpuElasticRhs`]: the PD local step fused with the elastic right-hand
//! side on the GPU (shader: `elastic.wgsl`).
//!
//! Per call: upload `x` (f32), one thread per tet computes `F`, the signed
//! SVD, `R(F)`, `V(F)` (VH Eq. 26 with the 0.01 floor, the algorithm of
//! [`crate::sim::local`]) and the four corner vectors
//! `2 V_e (γs R_e + γv V_e) ∇N_a^e`; one thread per node then sums its
//! corners over a node -> (tet, corner) incidence list in tet order (no
//! float atomics: deterministic), and a third pass reduces the energies and
//! clamp flags per workgroup. One submission, one readback (the result and
//! the partial sums together).

use super::{grid, grid_groups, to_u32, GpuContext, GpuError};
use crate::geom::Vec3;
use crate::sim::backend::{ElasticRhs, LocalEval};
use crate::sim::energy::ElasticModel;
use crate::sim::SimError;

const SHADER: &str = include_str!("elastic.wgsl");
/// Workgroup sizes of `tet_kernel` / `gather_kernel` and `reduce_kernel`.
const WG: u32 = 64;
const WG_REDUCE: u32 = 256;

/// The [`ElasticRhs`] of a fixed [`ElasticModel`] on the GPU (`f32`, see the
/// module doc of [`crate::sim::gpu`] for the precision).
pub struct GpuElasticRhs {
    ctx: GpuContext,
    num_nodes: usize,
    num_tets: usize,
    x_buf: wgpu::Buffer,
    params_buf: wgpu::Buffer,
    rest_buf: wgpu::Buffer,
    out_buf: wgpu::Buffer,
    partials_buf: wgpu::Buffer,
    staging: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    tet_pipeline: wgpu::ComputePipeline,
    gather_pipeline: wgpu::ComputePipeline,
    reduce_pipeline: wgpu::ComputePipeline,
    tet_grid: (u32, u32),
    node_grid: (u32, u32),
    reduce_grid: (u32, u32),
    x_f32: Vec<f32>,
}

impl std::fmt::Debug for GpuElasticRhs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuElasticRhs")
            .field("ctx", &self.ctx)
            .field("num_nodes", &self.num_nodes)
            .field("num_tets", &self.num_tets)
            .finish()
    }
}

fn f32_checked(v: f64, what: &str, tet: usize) -> Result<f32, GpuError> {
    let f = v as f32;
    if f.is_finite() {
        Ok(f)
    } else {
        Err(GpuError::Inconsistent(format!(
            "{what} of tet {tet} ({v}) does not fit in f32"
        )))
    }
}

/// Per tet: the three columns of `Dm⁻¹`, each followed by one of rest
/// volume, `γs`, `γv`, then two fibre families, each its unit direction
/// followed by its `γ` (zeros for a family the model lacks), then each
/// family's stiffening `β` and PD weight: 24 `f32`, the `rest` buffer's
/// layout.
fn rest_data(model: &ElasticModel) -> Result<Vec<f32>, GpuError> {
    let rest = model.rest();
    if model.fibres().len() > 2 {
        return Err(GpuError::Inconsistent(format!(
            "{} fibre families; the GPU kernel packs two",
            model.fibres().len()
        )));
    }
    let mut data: Vec<f32> = Vec::with_capacity(REST_F32_PER_TET * rest.len());
    for (e, r) in rest.iter().enumerate() {
        let extra = [
            (r.volume, "rest volume"),
            (model.gamma_s()[e], "gamma_s"),
            (model.gamma_v()[e], "gamma_v"),
        ];
        for (c, (w, what)) in extra.iter().enumerate() {
            for k in 0..3 {
                data.push(f32_checked(r.dm_inv[(k, c)], "Dm^-1", e)?);
            }
            data.push(f32_checked(*w, what, e)?);
        }
        for k in 0..2 {
            match model.fibres().get(k) {
                Some(fam) => {
                    for c in fam.directions[e] {
                        data.push(c as f32);
                    }
                    data.push(f32_checked(fam.gamma[e], "fibre gamma", e)?);
                }
                None => data.extend_from_slice(&[0.0; 4]),
            }
        }
        for k in 0..2 {
            match model.fibres().get(k) {
                Some(fam) => {
                    data.push(f32_checked(fam.beta_at(e), "fibre stiffening", e)?);
                    data.push(f32_checked(
                        fam.pd_weight(e, r.volume),
                        "fibre PD weight",
                        e,
                    )?);
                }
                None => data.extend_from_slice(&[0.0; 2]),
            }
        }
    }
    Ok(data)
}

/// The `Params` uniform of `elastic.wgsl`: tet and node counts and the
/// number of fibre families the kernel reads (0: it skips their data).
fn params_of(nt: usize, nn: usize, model: &ElasticModel) -> [u32; 4] {
    [nt as u32, nn as u32, model.fibres().len() as u32, 0]
}

/// `f32` per tet in the `rest` buffer (see [`rest_data`]).
const REST_F32_PER_TET: usize = 24;

impl GpuElasticRhs {
    /// Uploads the rest data of `model` (node indices, `Dm⁻¹`, rest volumes,
    /// `γs`, `γv`, all rounded to `f32`) and the node -> tet incidence once.
    pub fn new(ctx: &GpuContext, model: &ElasticModel) -> Result<GpuElasticRhs, GpuError> {
        let rest = model.rest();
        let nt = rest.len();
        let nn = model.num_nodes();
        to_u32(4 * nt, "4 x tet count")?;
        to_u32(3 * nn + 1, "3 x node count")?;
        let mut tets: Vec<u32> = Vec::with_capacity(4 * nt);
        for r in rest {
            for &i in &r.nodes {
                tets.push(to_u32(i, "node index")?);
            }
        }
        let rest_data = rest_data(model)?;
        // Node -> (tet, corner) incidence in CSR form, tet order within a node.
        let mut incidence = vec![0u32; nn + 1 + 4 * nt];
        for r in rest {
            for &i in &r.nodes {
                incidence[i + 1] += 1;
            }
        }
        for i in 0..nn {
            incidence[i + 1] += incidence[i];
        }
        let mut fill: Vec<u32> = incidence[..nn].to_vec();
        for (e, r) in rest.iter().enumerate() {
            for (c, &i) in r.nodes.iter().enumerate() {
                let pos = nn + 1 + fill[i] as usize;
                incidence[pos] = (4 * e + c) as u32;
                fill[i] += 1;
            }
        }

        ctx.fits("the per-tet corner vectors", 64 * nt as u64)?;
        ctx.fits("the node incidence", 4 * incidence.len() as u64)?;
        let tet_grid = grid(nt, WG)?;
        let node_grid = grid(nn, WG)?;
        let reduce_grid = grid(nt, WG_REDUCE)?;
        let n_partials = grid_groups(reduce_grid);

        let none = wgpu::BufferUsages::empty();
        let params = params_of(nt, nn, model);
        let params_buf = {
            use wgpu::util::DeviceExt;
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("elastic params"),
                    contents: bytemuck::cast_slice(&params),
                    // COPY_DST: a material update may add or drop fibres.
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                })
        };
        let tets_buf = ctx.storage_init("tets", bytemuck::cast_slice(&tets), none);
        // COPY_DST: new materials are written in place (update_materials).
        let rest_buf = ctx.storage_init(
            "rest",
            bytemuck::cast_slice(&rest_data),
            wgpu::BufferUsages::COPY_DST,
        );
        let inc_buf = ctx.storage_init("incidence", bytemuck::cast_slice(&incidence), none);
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let x_buf = ctx.buffer("x", 12 * nn as u64, storage);
        let corners_buf = ctx.buffer("corners", 64 * nt as u64, storage);
        let out_buf = ctx.buffer(
            "rhs",
            12 * nn as u64,
            storage | wgpu::BufferUsages::COPY_SRC,
        );
        let partials_buf = ctx.buffer(
            "energy partials",
            8 * n_partials as u64,
            storage | wgpu::BufferUsages::COPY_SRC,
        );
        let staging = ctx.buffer(
            "elastic staging",
            12 * nn as u64 + 8 * n_partials as u64,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );

        use wgpu::BufferBindingType as T;
        let ro = (T::Storage { read_only: true }, false);
        let rw = (T::Storage { read_only: false }, false);
        let (module, layout, pl) = ctx.kernel_layouts(
            "elastic.wgsl",
            SHADER,
            &[(T::Uniform, false), ro, ro, ro, rw, ro, rw, rw],
        );
        let bind_group = ctx.bind_buffers(
            "elastic bind group",
            &layout,
            &[
                &params_buf,
                &tets_buf,
                &rest_buf,
                &x_buf,
                &corners_buf,
                &inc_buf,
                &out_buf,
                &partials_buf,
            ],
        );
        let tet_pipeline = ctx.pipeline("tet_kernel", &pl, &module, "tet_kernel");
        let gather_pipeline = ctx.pipeline("gather_kernel", &pl, &module, "gather_kernel");
        let reduce_pipeline = ctx.pipeline("reduce_kernel", &pl, &module, "reduce_kernel");
        ctx.check("creating the elastic kernels")?;
        Ok(GpuElasticRhs {
            ctx: ctx.clone(),
            num_nodes: nn,
            num_tets: nt,
            x_buf,
            params_buf,
            rest_buf,
            out_buf,
            partials_buf,
            staging,
            bind_group,
            tet_pipeline,
            gather_pipeline,
            reduce_pipeline,
            tet_grid,
            node_grid,
            reduce_grid,
            x_f32: Vec::with_capacity(3 * nn),
        })
    }

    /// The context this kernel runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    fn run(&mut self, x: &[Vec3], out: &mut [Vec3]) -> Result<LocalEval, SimError> {
        let nn = self.num_nodes;
        if x.len() != nn || out.len() != nn {
            return Err(SimError::Inconsistent(format!(
                "GPU elastic rhs of {nn} nodes got {} positions and {} outputs",
                x.len(),
                out.len()
            )));
        }
        self.x_f32.clear();
        for (i, p) in x.iter().enumerate() {
            for &c in p {
                let v = c as f32;
                if !v.is_finite() {
                    return Err(SimError::Inconsistent(format!(
                        "position of node {i} ({p:?}) is not finite in f32"
                    )));
                }
                self.x_f32.push(v);
            }
        }
        let ctx = &self.ctx;
        ctx.queue
            .write_buffer(&self.x_buf, 0, bytemuck::cast_slice(&self.x_f32));
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("elastic rhs"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("elastic rhs"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &self.bind_group, &[]);
            if self.num_tets > 0 {
                pass.set_pipeline(&self.tet_pipeline);
                pass.dispatch_workgroups(self.tet_grid.0, self.tet_grid.1, 1);
            }
            pass.set_pipeline(&self.gather_pipeline);
            pass.dispatch_workgroups(self.node_grid.0, self.node_grid.1, 1);
            pass.set_pipeline(&self.reduce_pipeline);
            pass.dispatch_workgroups(self.reduce_grid.0, self.reduce_grid.1, 1);
        }
        let out_bytes = 12 * nn as u64;
        let n_partials = grid_groups(self.reduce_grid);
        if out_bytes > 0 {
            encoder.copy_buffer_to_buffer(&self.out_buf, 0, &self.staging, 0, out_bytes);
        }
        encoder.copy_buffer_to_buffer(
            &self.partials_buf,
            0,
            &self.staging,
            out_bytes,
            8 * n_partials as u64,
        );
        let bytes = ctx.submit_and_read(
            encoder,
            &self.staging,
            out_bytes + 8 * n_partials as u64,
            "elastic rhs",
        )?;
        let vals: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
        for (i, o) in out.iter_mut().enumerate() {
            for k in 0..3 {
                let v = vals[3 * i + k];
                if !v.is_finite() {
                    return Err(SimError::Inconsistent(format!(
                        "GPU elastic rhs is not finite at node {i} (f32 overflow?)"
                    )));
                }
                o[k] = v as f64;
            }
        }
        let (mut energy, mut clamped) = (0.0f64, 0.0f64);
        for p in vals[3 * nn..3 * nn + 2 * n_partials].chunks_exact(2) {
            energy += p[0] as f64;
            clamped += p[1] as f64;
        }
        Ok(LocalEval {
            elastic_energy: energy,
            clamped_tets: clamped.round().max(0.0) as usize,
        })
    }
}

impl ElasticRhs for GpuElasticRhs {
    fn evaluate(&mut self, x: &[Vec3], out: &mut [Vec3]) -> Result<LocalEval, SimError> {
        self.run(x, out)
    }

    fn name(&self) -> &'static str {
        "gpu"
    }

    /// Per-tet energies in f32, summed per workgroup in f32.
    fn energy_precision(&self) -> f64 {
        1e-5
    }

    fn update_materials(&mut self, model: &ElasticModel) -> Result<bool, SimError> {
        if model.rest().len() != self.num_tets || model.num_nodes() != self.num_nodes {
            return Ok(false);
        }
        let data = rest_data(model).map_err(|e| SimError::Inconsistent(e.to_string()))?;
        self.ctx
            .queue
            .write_buffer(&self.rest_buf, 0, bytemuck::cast_slice(&data));
        let params = params_of(self.num_tets, self.num_nodes, model);
        self.ctx
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::cast_slice(&params));
        Ok(true)
    }
}
