//! `fascicle select`: keep the streamlines of a tractogram that meet every include region and no exclude region,
//! as MRtrix3's `tckedit` keeps them (`fascicle_core::roi`: a point of the streamline in a sphere, box or mask;
//! with `--ends-only` its two ends), cut where they leave `--mask` regions (`tckedit -mask`), and write them as
//! `.tck`, `.trk` or `.trx`.
//!
//! The file is streamed: one thread reads chunks of streamlines while the others test them and the kept ones
//! are written, so memory stays bounded (a few chunks) whatever the file's size.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use fascicle_core::Error;
use fascicle_core::io::stream::{self, DEFAULT_CHUNK_POINTS, Format, TractogramReader, TractogramWriter, WriteOptions};
use fascicle_core::io::{Tractogram, tck, tractogram::extension, trk, weights};
use fascicle_core::roi::{Criteria, MaskRegion, Region, Roi, RoiMode, RoiShape};
use glam::DMat4;
use rayon::prelude::*;

/// The options of `fascicle select`.
#[derive(clap::Args, Debug)]
pub struct SelectArgs {
    /// Input tractogram (.tck, .trk, gzipped, or .trx).
    pub input: PathBuf,
    /// Include region (repeatable), as tckedit's -include: a sphere X,Y,Z,R (RAS+ mm) or a mask image (NIfTI or
    /// .mif; its non-zero voxels).
    #[arg(long, value_name = "X,Y,Z,R|IMAGE", allow_hyphen_values = true)]
    pub include: Vec<String>,
    /// Exclude region (repeatable), as tckedit's -exclude: a sphere X,Y,Z,R or a mask image.
    #[arg(long, value_name = "X,Y,Z,R|IMAGE", allow_hyphen_values = true)]
    pub exclude: Vec<String>,
    /// Test only the first and last point of each streamline against the regions (tckedit's -ends_only).
    #[arg(long)]
    pub ends_only: bool,
    /// Include sphere, x,y,z,r in RAS+ mm (repeatable; the same as --include X,Y,Z,R).
    #[arg(long, value_name = "X,Y,Z,R", allow_hyphen_values = true)]
    pub sphere: Vec<String>,
    /// Exclude sphere, x,y,z,r (repeatable).
    #[arg(long, value_name = "X,Y,Z,R", allow_hyphen_values = true)]
    pub exclude_sphere: Vec<String>,
    /// Include axis-aligned box, x0,y0,z0,x1,y1,z1 (repeatable; faces included).
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", name = "box", allow_hyphen_values = true)]
    pub boxes: Vec<String>,
    /// Exclude box (repeatable).
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", allow_hyphen_values = true)]
    pub exclude_box: Vec<String>,
    /// Include plane through a point with a normal, px,py,pz,nx,ny,nz (repeatable): a step of the streamline
    /// crosses it.
    #[arg(long, value_name = "PX,PY,PZ,NX,NY,NZ", allow_hyphen_values = true)]
    pub plane: Vec<String>,
    /// Exclude plane (repeatable).
    #[arg(long, value_name = "PX,PY,PZ,NX,NY,NZ", allow_hyphen_values = true)]
    pub exclude_plane: Vec<String>,
    /// Mask region (repeatable), as tckedit's -mask: a sphere X,Y,Z,R or a mask image; kept streamlines are cut
    /// where they leave the union of the masks, each run of two or more points inside written as a streamline.
    /// Values per point or per streamline are not carried through the cut.
    #[arg(long, value_name = "X,Y,Z,R|IMAGE", allow_hyphen_values = true)]
    pub mask: Vec<String>,
    /// Streamline weights, one per input streamline (tcksift2's output; as tckedit's -tck_weights_in).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Keep only streamlines whose weight is at least this (tckedit's -minweight; needs --weights).
    #[arg(long = "min-weight", visible_alias = "min", requires = "weights")]
    pub min_weight: Option<f32>,
    /// Write the kept streamlines' weights here, in their order (tckedit's -tck_weights_out; needs --weights);
    /// with --mask, one per piece written, its streamline's weight.
    #[arg(long, requires = "weights")]
    pub weights_out: Option<PathBuf>,
    /// Output (.tck, .trk, gzipped, or .trx).
    #[arg(long)]
    pub out: PathBuf,
}

fn numbers(s: &str, n: usize, what: &str) -> Result<Vec<f32>, Error> {
    // Parsed as f64 and rounded to f32, as MRtrix3 parses an ROI (so a radius is the same float in both tools).
    let v: Vec<f32> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .map(|v| v as f32)
                .map_err(|_| Error::Param(format!("{what} '{s}': '{x}' is not a number")))
        })
        .collect::<Result<_, _>>()?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(Error::Param(format!("{what} '{s}' needs {n} finite comma-separated numbers")));
    }
    Ok(v)
}

/// The ROIs the arguments describe.
pub fn rois(a: &SelectArgs) -> Result<Vec<Roi>, Error> {
    let mut out = Vec::new();
    for (list, mode) in [(&a.sphere, RoiMode::Include), (&a.exclude_sphere, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 4, "sphere")?;
            if v[3] <= 0.0 {
                return Err(Error::Param(format!("sphere '{s}': the radius must be positive")));
            }
            out.push(Roi { shape: RoiShape::Sphere { centre: [v[0], v[1], v[2]], radius: v[3] }, mode });
        }
    }
    for (list, mode) in [(&a.boxes, RoiMode::Include), (&a.exclude_box, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 6, "box")?;
            let (lo, hi) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
            out.push(Roi {
                shape: RoiShape::Box {
                    min: std::array::from_fn(|k| lo[k].min(hi[k])),
                    max: std::array::from_fn(|k| lo[k].max(hi[k])),
                },
                mode,
            });
        }
    }
    for (list, mode) in [(&a.plane, RoiMode::Include), (&a.exclude_plane, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 6, "plane")?;
            if v[3..].iter().all(|x| *x == 0.0) {
                return Err(Error::Param(format!("plane '{s}': the normal must not be zero")));
            }
            out.push(Roi { shape: RoiShape::Plane { point: [v[0], v[1], v[2]], normal: [v[3], v[4], v[5]] }, mode });
        }
    }
    Ok(out)
}

/// Writes `t` to `.trk` (with the reference space of `header` when the input was a `.trk`, else a 1 mm grid
/// covering the points) or `.tck`, chosen by the extension.
pub fn write(path: &Path, t: &Tractogram, header: Option<&trk::TrkHeader>) -> Result<(), Error> {
    match extension(path).as_str() {
        "trk" => {
            let (affine, dims) = match header {
                Some(h) if h.vox_to_ras != DMat4::ZERO && h.dims.iter().all(|d| *d > 0) => {
                    (h.vox_to_ras, h.dims.map(|d| d as usize))
                }
                _ => {
                    let lo = t.points.iter().copied().reduce(glam::Vec3::min);
                    let hi = t.points.iter().copied().reduce(glam::Vec3::max);
                    stream::grid_over(lo.zip(hi))
                }
            };
            trk::write(path, t, affine, dims)
        }
        "tck" => tck::write(path, t, &[]),
        "trx" => fascicle_core::io::trx::write(path, t, None, fascicle_core::io::trx::PositionType::F32),
        other => Err(Error::Param(format!(
            "output '{}': unknown extension '{other}' (use .trk, .tck or .trx)",
            path.display()
        ))),
    }
}

/// A sphere "X,Y,Z,R" or, when the text is not four numbers, a mask image (as tckedit reads an ROI).
fn region(spec: &str) -> Result<Region, Error> {
    let looks_numeric = spec.split(',').count() == 4 && !Path::new(spec).exists();
    if looks_numeric {
        let v = numbers(spec, 4, "sphere")?;
        if v[3] <= 0.0 {
            return Err(Error::Param(format!("sphere '{spec}': the radius must be positive")));
        }
        return Ok(Region::Shape(RoiShape::Sphere { centre: [v[0], v[1], v[2]], radius: v[3] }));
    }
    let path = Path::new(spec);
    if !path.exists() {
        return Err(Error::Param(format!("region '{spec}' is neither a sphere X,Y,Z,R nor an image file")));
    }
    let vol = fascicle_core::io::mif::read_image::<f32>(path)?;
    let mask = MaskRegion::new(&vol);
    if mask.count() == 0 {
        return Err(Error::Param(format!("{spec}: the mask image is empty (no non-zero voxel)")));
    }
    Ok(Region::Mask(Arc::new(mask)))
}

/// What the arguments select.
pub fn criteria(a: &SelectArgs) -> Result<Criteria, Error> {
    let mut c = Criteria { ends_only: a.ends_only, ..Default::default() };
    for spec in &a.include {
        c.include.push(region(spec)?);
    }
    for spec in &a.exclude {
        c.exclude.push(region(spec)?);
    }
    for roi in rois(a)? {
        match roi.mode {
            RoiMode::Include => c.include.push(Region::Shape(roi.shape)),
            RoiMode::Exclude => c.exclude.push(Region::Shape(roi.shape)),
        }
    }
    if c.include.len() > 64 {
        return Err(Error::Param(format!("{} include regions: at most 64", c.include.len())));
    }
    if a.ends_only && (!a.plane.is_empty() || !a.exclude_plane.is_empty()) {
        return Err(Error::Param("--ends-only tests points; a plane is met by crossing it: use a box".into()));
    }
    Ok(c)
}

/// How a tractogram written from `header`'s file is placed: its values where the output format holds them,
/// the `.tck` header entries, the TRX grid (without groups when the streamlines change), and for a `.trk` the
/// input's grid (a 1 mm grid over the input's points for a `.tck`, read in one more pass).
pub fn write_options(
    input: &Path,
    header: &stream::StreamHeader,
    output: &Path,
    keep_groups: bool,
) -> Result<WriteOptions, Error> {
    let mut options = WriteOptions {
        tck_header: header.tck.clone().unwrap_or_default(),
        scalars: header.scalars.clone(),
        properties: header.properties.clone(),
        trx: header.trx.clone().map(|mut h| {
            if !keep_groups {
                h.groups.clear();
            }
            h
        }),
        ..Default::default()
    };
    if Format::of(output)? == Format::Trk {
        let bounds = if header.trk.is_none() && header.trx.is_none() {
            let mut r = TractogramReader::open(input)?;
            stream::scan(&mut r, |_| {})?.bounds
        } else {
            None
        };
        options.trk_space = Some(stream::trk_space(header, bounds));
        if options.scalars.len() > 10 || options.properties.len() > 10 {
            return Err(Error::Param(format!(
                "{}: {} values per point and {} per streamline; a .trk holds at most 10 of each",
                input.display(),
                options.scalars.len(),
                options.properties.len()
            )));
        }
    }
    Ok(options)
}

/// A progress bar over a file's bytes.
pub(crate) fn bytes_bar(total: u64, what: &str) -> indicatif::ProgressBar {
    if super::globals().quiet {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(total);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec}, eta {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    pb.set_message(what.to_string());
    pb
}

/// Streams `input` through `keep` (per chunk, which streamlines to write) into `writer`, each kept streamline
/// cut to its pieces inside `crop` when there are such regions ([`fascicle_core::roi::pieces_inside`], points
/// only): one thread reads while the caller's threads test and write. After each chunk written, `pieces` gets,
/// per kept streamline of the chunk in order, how many streamlines it was written as (1 uncut; 0 or more cut).
/// The streamlines read and written.
pub fn pipe(
    reader: TractogramReader,
    writer: &mut TractogramWriter,
    what: &str,
    keep: impl Fn(&Tractogram) -> Result<Option<Vec<bool>>, Error> + Sync,
    crop: &[Region],
    mut pieces: impl FnMut(&[usize]) -> Result<(), Error>,
) -> Result<(usize, usize), Error> {
    let pb = bytes_bar(reader.header().file_bytes, what);
    let (mut read, mut written) = (0, 0);
    std::thread::scope(|scope| -> Result<(), Error> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Result<(Tractogram, u64), Error>>(2);
        let mut reader = reader;
        scope.spawn(move || {
            loop {
                match reader.next_chunk(DEFAULT_CHUNK_POINTS) {
                    Ok(Some(t)) => {
                        if tx.send(Ok((t, reader.bytes_read()))).is_err() {
                            return;
                        }
                    }
                    Ok(None) => return,
                    Err(e) => {
                        tx.send(Err(e)).ok();
                        return;
                    }
                }
            }
        });
        for msg in rx {
            let (t, bytes) = msg?;
            read += t.n_streamlines();
            match keep(&t)? {
                Some(mask) if !crop.is_empty() => {
                    let mut out = Tractogram::new();
                    let mut counts = vec![];
                    for s in (0..t.n_streamlines()).filter(|s| mask[*s]) {
                        let pts = t.streamline(s);
                        let cut = fascicle_core::roi::pieces_inside(pts, crop);
                        counts.push(cut.len());
                        for piece in cut {
                            out.push(&pts[piece]);
                        }
                    }
                    written += out.n_streamlines();
                    writer.write_chunk(&out)?;
                    pieces(&counts)?;
                }
                Some(mask) => {
                    let out = t.subset_with_values(&mask);
                    written += out.n_streamlines();
                    writer.write_chunk(&out)?;
                    pieces(&vec![1; out.n_streamlines()])?;
                }
                None => {
                    written += t.n_streamlines();
                    writer.write_chunk(&t)?;
                    pieces(&vec![1; t.n_streamlines()])?;
                }
            }
            pb.set_position(bytes);
        }
        Ok(())
    })?;
    pb.finish_and_clear();
    Ok((read, written))
}

/// Runs `fascicle select`: streams the input through the regions (and --min-weight) into --out, with a summary
/// on stdout.
pub fn run(a: SelectArgs) -> Result<(), Error> {
    let criteria = criteria(&a)?;
    super::check_output(&a.out)?;
    let t0 = std::time::Instant::now();
    if let Some(w) = &a.weights_out {
        super::check_output(w)?;
    }
    let crop = a.mask.iter().map(|spec| region(spec)).collect::<Result<Vec<_>, _>>()?;
    let reader = TractogramReader::open(&a.input)?;
    let mut options = write_options(&a.input, reader.header(), &a.out, false)?;
    if !crop.is_empty() {
        // The pieces carry points only.
        options.scalars.clear();
        options.properties.clear();
    }
    let mut writer = TractogramWriter::create(&a.out, &options)?;
    // Weights are read in step with the chunks (the consumer takes the chunks in order); the kept ones wait for
    // the chunk's pieces, each of which carries its streamline's weight (as tckedit writes them).
    let weights = match &a.weights {
        Some(p) => Some(std::sync::Mutex::new((
            weights::WeightReader::open(p)?,
            a.weights_out.as_ref().map(weights::WeightWriter::create).transpose()?,
            Vec::<f32>::new(),
        ))),
        None => None,
    };
    let min_weight = a.min_weight.unwrap_or(f32::NEG_INFINITY);
    let keep = |t: &Tractogram| -> Result<Option<Vec<bool>>, Error> {
        let mut mask: Vec<bool> =
            (0..t.n_streamlines()).into_par_iter().with_min_len(256).map(|s| criteria.keeps(t.streamline(s))).collect();
        if let Some(w) = &weights {
            let mut guard = w.lock().unwrap_or_else(|e| e.into_inner());
            let (reader, out, pending) = &mut *guard;
            let ws = reader.take(t.n_streamlines())?;
            for (k, w) in mask.iter_mut().zip(&ws) {
                *k &= *w >= min_weight;
            }
            if out.is_some() {
                *pending = ws.iter().zip(&mask).filter(|(_, k)| **k).map(|(w, _)| *w).collect();
            }
        }
        Ok(Some(mask))
    };
    let write_weights = |counts: &[usize]| -> Result<(), Error> {
        let Some(w) = &weights else { return Ok(()) };
        let mut guard = w.lock().unwrap_or_else(|e| e.into_inner());
        let (_, out, pending) = &mut *guard;
        if let Some(out) = out {
            let each: Vec<f32> = pending.iter().zip(counts).flat_map(|(w, n)| std::iter::repeat_n(*w, *n)).collect();
            out.write(&each)?;
        }
        Ok(())
    };
    let (read, _) = pipe(reader, &mut writer, "select", keep, &crop, write_weights)?;
    let weights_out = match weights {
        Some(w) => {
            let (reader, out, _) = w.into_inner().unwrap_or_else(|e| e.into_inner());
            reader.finish(read as u64)?;
            out
        }
        None => None,
    };
    let kept = writer.finish()?;
    if let Some(out) = weights_out {
        out.finish()?;
    }
    if super::globals().quiet {
        return Ok(());
    }
    let n_regions = criteria.include.len() + criteria.exclude.len() + crop.len();
    println!(
        "kept {kept} of {read} streamlines ({n_regions} regions, {:.1} s) -> {}",
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}
