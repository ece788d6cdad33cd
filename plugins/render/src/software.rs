//! Mesa's software rasterizer (lavapipe, llvmpipe): how many threads it rasterizes on.
//!
//! Lavapipe draws in two stages: one thread runs the vertex stage and bins each primitive into the screen tiles
//! it covers (a "scene" of up to a few tens of MB), and `LP_NUM_THREADS` threads (by default one per core)
//! rasterize the binned scenes. Binning a line costs far less than rasterizing its pixels, so on few cores the
//! binning thread runs ahead and fills scene after scene; lavapipe allocates scenes as they are needed and
//! keeps them for the life of the device. With more rasterizer threads than cores the binning thread gets a
//! smaller share of the CPU and stays closer to the rasterizers. A million streamlines (13M line segments) on
//! 2 cores, rasterizer threads 2 (the default) / 4 / 8: `fascicle render` peaked at 2.32-2.54 / 1.65-1.90 /
//! 1.33-1.42 GB in 5.5-6.0 s each; the viewer's tractogram layer at 2.04-2.32 / 1.17-1.46 / 1.09-1.27 GiB,
//! complete on screen in 7.8 / 8.3-8.6 / 8.7-9.8 s. Frames whose cost is the vertex stage lose a little: a
//! 10M tract layer with an ROI completed in 31 s with 2 threads, 36 s with 4.

/// Rasterizer threads lavapipe is given per core ([`oversubscribe_software_rasterizer`]): 2.
pub const SOFTWARE_RASTER_THREADS_PER_CORE: usize = 2;

/// The `LP_NUM_THREADS` to set on a machine of `cores` cores when the user set none (`user`):
/// [`SOFTWARE_RASTER_THREADS_PER_CORE`] a core; `None` leaves the user's value.
pub fn software_raster_threads(user: Option<&std::ffi::OsStr>, cores: usize) -> Option<usize> {
    user.is_none().then_some(cores.max(1) * SOFTWARE_RASTER_THREADS_PER_CORE)
}

/// Sets `LP_NUM_THREADS` to [`software_raster_threads`] unless the environment already holds it. Only Mesa's
/// software rasterizers read it (a hardware adapter is not affected); it must be set before the renderer
/// starts, as lavapipe reads it once.
///
/// # Safety
/// Writes the process environment: call it before any other thread starts (first thing in `main`), as
/// [`std::env::set_var`] requires.
pub unsafe fn oversubscribe_software_rasterizer() {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    if let Some(threads) = software_raster_threads(std::env::var_os("LP_NUM_THREADS").as_deref(), cores) {
        // SAFETY: the caller guarantees no other thread runs yet.
        unsafe { std::env::set_var("LP_NUM_THREADS", threads.to_string()) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raster_threads_oversubscribe_the_cores_and_keep_the_users_choice() {
        assert_eq!(software_raster_threads(None, 2), Some(4));
        assert_eq!(software_raster_threads(None, 0), Some(2));
        assert_eq!(software_raster_threads(Some("0".as_ref()), 2), None);
    }
}
