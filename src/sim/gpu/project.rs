//! Per-node collision projection on the GPU (shader: `project.wgsl`): the
//! closest admissible position of every node against a list of planes and
//! spheres, the projection constraints of VH §8.5 (Bouaziz et al. 2014 §5).
//!
//! Colliders are applied in list order, one pass (the same as
//! [`project_point`], the `f64` CPU version, which also serves as a
//! [`NodeProjector`] through [`Colliders`]).

use super::{grid, to_u32, GpuContext, GpuError};
use crate::geom::Vec3;
use crate::sim::contact::NodeProjector;

const SHADER: &str = include_str!("project.wgsl");
const WG: u32 = 64;

/// A collider of the GPU projection. Lengths in m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Collider {
    /// The half-space below the plane through `point` with outward `normal`
    /// (any length > 0; normalized on use): admissible nodes lie at least
    /// `thickness` above the plane.
    Plane {
        point: Vec3,
        normal: Vec3,
        thickness: f64,
    },
    /// A solid ball: admissible nodes lie at least `radius + thickness` from
    /// `center`. A node exactly at the centre is pushed along +Y.
    Sphere {
        center: Vec3,
        radius: f64,
        thickness: f64,
    },
}

impl Collider {
    fn validate(&self, index: usize) -> Result<(), GpuError> {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let ok = match self {
            Collider::Plane {
                point,
                normal,
                thickness,
            } => {
                finite(point)
                    && finite(normal)
                    && thickness.is_finite()
                    && normal.iter().map(|x| x * x).sum::<f64>() > 0.0
            }
            Collider::Sphere {
                center,
                radius,
                thickness,
            } => finite(center) && radius.is_finite() && *radius >= 0.0 && thickness.is_finite(),
        };
        if ok {
            Ok(())
        } else {
            Err(GpuError::Inconsistent(format!(
                "collider {index} is invalid: {self:?}"
            )))
        }
    }
}

fn unit(v: Vec3) -> Vec3 {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / l, v[1] / l, v[2] / l]
}

/// The closest admissible position of `p` (m) against `colliders` in order,
/// or `None` when `p` is admissible (`f64`, the CPU twin of the shader).
pub fn project_point(colliders: &[Collider], p: Vec3) -> Option<Vec3> {
    let mut q = p;
    let mut moved = false;
    for c in colliders {
        match *c {
            Collider::Plane {
                point,
                normal,
                thickness,
            } => {
                let n = unit(normal);
                let d = (0..3).map(|k| (q[k] - point[k]) * n[k]).sum::<f64>();
                if d < thickness {
                    for k in 0..3 {
                        q[k] += (thickness - d) * n[k];
                    }
                    moved = true;
                }
            }
            Collider::Sphere {
                center,
                radius,
                thickness,
            } => {
                let v = [q[0] - center[0], q[1] - center[1], q[2] - center[2]];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let r = radius + thickness;
                if l < r {
                    q = if l > 0.0 {
                        [0, 1, 2].map(|k| center[k] + v[k] * (r / l))
                    } else {
                        [center[0], center[1] + r, center[2]]
                    };
                    moved = true;
                }
            }
        }
    }
    moved.then_some(q)
}

/// A collider list as a [`NodeProjector`] (CPU, `f64`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Colliders(pub Vec<Collider>);

impl NodeProjector for Colliders {
    fn project(&self, _node: usize, p: Vec3) -> Option<Vec3> {
        project_point(&self.0, p)
    }
}

/// Projects the nodes of a mesh of fixed size against colliders on the GPU.
pub struct GpuNodeProjector {
    ctx: GpuContext,
    num_nodes: usize,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    params_buf: wgpu::Buffer,
    x_buf: wgpu::Buffer,
    out_buf: wgpu::Buffer,
    staging: wgpu::Buffer,
    node_grid: (u32, u32),
}

impl std::fmt::Debug for GpuNodeProjector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuNodeProjector")
            .field("ctx", &self.ctx)
            .field("num_nodes", &self.num_nodes)
            .finish()
    }
}

impl GpuNodeProjector {
    /// Buffers for `num_nodes` nodes.
    pub fn new(ctx: &GpuContext, num_nodes: usize) -> Result<GpuNodeProjector, GpuError> {
        to_u32(3 * num_nodes, "3 x node count")?;
        ctx.fits("the projected nodes", 16 * num_nodes as u64)?;
        let node_grid = grid(num_nodes, WG)?;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let params_buf = ctx.buffer(
            "project params",
            16,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let x_buf = ctx.buffer("project x", 12 * num_nodes as u64, storage);
        let out_buf = ctx.buffer(
            "projected",
            16 * num_nodes as u64,
            storage | wgpu::BufferUsages::COPY_SRC,
        );
        let staging = ctx.buffer(
            "project staging",
            16 * num_nodes as u64,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        use wgpu::BufferBindingType as T;
        let ro = (T::Storage { read_only: true }, false);
        let (module, layout, pl) = ctx.kernel_layouts(
            "project.wgsl",
            SHADER,
            &[
                (T::Uniform, false),
                ro,
                ro,
                (T::Storage { read_only: false }, false),
            ],
        );
        let pipeline = ctx.pipeline("project_kernel", &pl, &module, "project_kernel");
        ctx.check("creating the projection kernel")?;
        Ok(GpuNodeProjector {
            ctx: ctx.clone(),
            num_nodes,
            layout,
            pipeline,
            params_buf,
            x_buf,
            out_buf,
            staging,
            node_grid,
        })
    }

    /// For every node at `x` (m), its closest admissible position against
    /// `colliders` (in order) or `None` when admissible; returns the number
    /// of projected nodes. `f32` on the device: positions agree with
    /// [`project_point`] to about `1e-7` times the coordinates' magnitude.
    pub fn project_nodes(
        &mut self,
        x: &[Vec3],
        colliders: &[Collider],
        out: &mut [Option<Vec3>],
    ) -> Result<usize, GpuError> {
        let n = self.num_nodes;
        if x.len() != n || out.len() != n {
            return Err(GpuError::Inconsistent(format!(
                "projection of {n} nodes got {} positions and {} outputs",
                x.len(),
                out.len()
            )));
        }
        for (i, c) in colliders.iter().enumerate() {
            c.validate(i)?;
        }
        let mut packed: Vec<f32> = Vec::with_capacity(8 * colliders.len());
        for c in colliders {
            let v = match *c {
                Collider::Plane {
                    point,
                    normal,
                    thickness,
                } => {
                    let nn = unit(normal);
                    [
                        point[0], point[1], point[2], 0.0, nn[0], nn[1], nn[2], thickness,
                    ]
                }
                Collider::Sphere {
                    center,
                    radius,
                    thickness,
                } => [
                    center[0], center[1], center[2], 1.0, radius, 0.0, 0.0, thickness,
                ],
            };
            packed.extend(v.iter().map(|&f| f as f32));
        }
        let mut xs: Vec<f32> = Vec::with_capacity(3 * n);
        for (i, p) in x.iter().enumerate() {
            for &c in p {
                let v = c as f32;
                if !v.is_finite() {
                    return Err(GpuError::Inconsistent(format!(
                        "position of node {i} ({p:?}) is not finite in f32"
                    )));
                }
                xs.push(v);
            }
        }
        let ctx = &self.ctx;
        let params: [u32; 4] = [n as u32, to_u32(colliders.len(), "collider count")?, 0, 0];
        ctx.queue
            .write_buffer(&self.params_buf, 0, bytemuck::cast_slice(&params));
        ctx.queue
            .write_buffer(&self.x_buf, 0, bytemuck::cast_slice(&xs));
        let colliders_buf = ctx.storage_init(
            "colliders",
            bytemuck::cast_slice(&packed),
            wgpu::BufferUsages::empty(),
        );
        let bind_group = ctx.bind_buffers(
            "project bind group",
            &self.layout,
            &[&self.params_buf, &self.x_buf, &colliders_buf, &self.out_buf],
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("project nodes"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("project nodes"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(self.node_grid.0, self.node_grid.1, 1);
        }
        let size = 16 * n as u64;
        if size > 0 {
            encoder.copy_buffer_to_buffer(&self.out_buf, 0, &self.staging, 0, size);
        }
        let bytes = ctx.submit_and_read(encoder, &self.staging, size, "node projection")?;
        let vals: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
        let mut count = 0;
        for (i, o) in out.iter_mut().enumerate() {
            let v = &vals[4 * i..4 * i + 4];
            *o = if v[3] > 0.5 {
                count += 1;
                Some([v[0] as f64, v[1] as f64, v[2] as f64])
            } else {
                None
            };
        }
        Ok(count)
    }
}
