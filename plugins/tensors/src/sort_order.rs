//! How splat sets are ordered, shared by the CPU sort ([`crate::splat`]) and the GPU sort
//! ([`crate::gpu_sort`]): the mode a resource picks, what the GPU sort has done, and the padded length of an
//! order.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};

use bevy::prelude::*;

/// How splat sets are sorted (a resource; the viewer uses the default).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SplatSortMode {
    /// The GPU on a hardware adapter; the CPU on a software rasteriser (lavapipe, llvmpipe, WARP), where the
    /// CPU's radix sort is faster than an emulated GPU running the bitonic network (`bench splats`: 100k
    /// splats orbit at 145 ms a frame with the CPU sort, 261 ms with the GPU's, on lavapipe).
    #[default]
    Auto,
    /// A compute pass per view (the CPU where the adapter has no compute shaders).
    Gpu,
    /// The CPU's radix argsort, the order uploaded (4 bytes per splat) when the view direction changes.
    Cpu,
}

/// What the GPU sort has done, shared by the main and render worlds (a resource in both).
#[derive(Resource, Clone, Default)]
pub struct GpuSortStats(pub(crate) Arc<Shared>);

#[derive(Default)]
pub(crate) struct Shared {
    pub(crate) sorts: AtomicU64,
    /// 0 not known yet, 1 compute shaders available, 2 not.
    pub(crate) compute: AtomicU8,
    /// The adapter is a software rasteriser.
    pub(crate) software: std::sync::atomic::AtomicBool,
    pub(crate) last_forward: std::sync::Mutex<Option<Vec3>>,
}

impl GpuSortStats {
    /// Sorts done on the GPU so far.
    pub fn sorts(&self) -> u64 {
        self.0.sorts.load(Ordering::Relaxed)
    }
    /// The world view direction of the last GPU sort.
    pub fn last_forward(&self) -> Option<Vec3> {
        *self.0.last_forward.lock().unwrap_or_else(|e| e.into_inner())
    }
    /// Whether `mode` sorts on the GPU on this adapter (as far as is known: before the renderer has started,
    /// `Gpu` says yes and `Auto` no).
    pub fn uses_gpu(&self, mode: SplatSortMode) -> bool {
        let compute = self.0.compute.load(Ordering::Relaxed);
        match mode {
            SplatSortMode::Cpu => false,
            SplatSortMode::Gpu => compute != 2,
            SplatSortMode::Auto => compute == 1 && !self.0.software.load(Ordering::Relaxed),
        }
    }
}

/// The padded length of a set's order: a power of two, at least one block (512).
pub fn padded_len(n: usize) -> usize {
    n.max(512).next_power_of_two()
}
