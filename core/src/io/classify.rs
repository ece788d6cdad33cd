//! What a NIfTI image holds, told from its header, the files beside it and, where those are silent, its
//! content: a DWI (bval/bvec beside it), a diffusion tensor (6 volumes, in DIPY's, FSL's or MRtrix's element
//! order), SH coefficients (15, 28, 45, ... volumes, the basis from the header or a JSON sidecar), peaks, an
//! RGB map, a scalar map or some other 4D series.
//!
//! Evidence, strongest first: NIfTI intent codes (symmetric matrix, vector, RGB vector) and the RGB datatypes;
//! gradient files beside the image; a JSON sidecar (`sh_basis`, `model`); the basis in `descrip` as
//! `fascicle fit` writes it; "peak" in the name or intent name; then the content (tensor element orders by the
//! share of positive-definite voxels, SH by a positive `c00` everywhere there is signal). When the content is
//! not conclusive the answer is marked [`Classified::ambiguous`], with the alternatives, for the caller to ask.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::nifti::{self, NiftiHeader};
use crate::sh::{self, ShBasis};
use crate::{Result, Volume};

/// NIfTI intent codes used here.
pub const INTENT_SYMMATRIX: i32 = 1005;
/// NIfTI intent code `NIFTI_INTENT_VECTOR`: each voxel holds a vector (read as peaks when the volumes come in
/// threes).
pub const INTENT_VECTOR: i32 = 1007;
/// NIfTI intent code `NIFTI_INTENT_RGB_VECTOR`: each voxel holds an RGB colour (an RGB map).
pub const INTENT_RGB_VECTOR: i32 = 2003;
/// NIfTI datatypes RGB24 and RGBA32.
const DT_RGB24: i16 = 128;
const DT_RGBA32: i16 = 2304;

/// The element order of a 6-volume tensor image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum TensorOrder {
    /// DIPY and nibabel: lower triangle by rows, Dxx Dxy Dyy Dxz Dyz Dzz.
    #[default]
    Dipy,
    /// FSL `dtifit --save_tensor`: upper triangle by rows, Dxx Dxy Dxz Dyy Dyz Dzz.
    Fsl,
    /// MRtrix3 `dwi2tensor`: diagonal first, D11 D22 D33 D12 D13 D23.
    Mrtrix,
}

impl TensorOrder {
    /// Every order, DIPY's first (the one kept when several fit equally well).
    pub const ALL: [TensorOrder; 3] = [TensorOrder::Dipy, TensorOrder::Fsl, TensorOrder::Mrtrix];

    /// For each DIPY slot (Dxx Dxy Dyy Dxz Dyz Dzz), the volume of this order that holds it.
    pub fn dipy_slots(self) -> [usize; 6] {
        match self {
            TensorOrder::Dipy => [0, 1, 2, 3, 4, 5],
            TensorOrder::Fsl => [0, 1, 3, 2, 4, 5],
            TensorOrder::Mrtrix => [0, 3, 1, 4, 5, 2],
        }
    }

    /// Reorders a (X,Y,Z,6) image of this order into DIPY's order, in place.
    pub fn to_dipy(self, vol: &mut Volume<f32>) {
        if self == TensorOrder::Dipy || vol.n_channels() != 6 {
            return;
        }
        let n = vol.n_voxels();
        let old = vol.data.clone();
        for (slot, &src) in self.dipy_slots().iter().enumerate() {
            vol.data[slot * n..(slot + 1) * n].copy_from_slice(&old[src * n..(src + 1) * n]);
        }
    }
}

/// What an image holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ImageKind {
    /// Diffusion-weighted volumes with their gradient table beside the image.
    Dwi {
        /// The b-values file beside the image (`x.bval`).
        bval: PathBuf,
        /// The b-vectors file beside the image (`x.bvec`).
        bvec: PathBuf,
    },
    /// A diffusion tensor image: 6 volumes holding the unique elements of the symmetric matrix.
    Tensor {
        /// The order of the 6 elements in the volumes ([`TensorOrder::to_dipy`] reorders them).
        order: TensorOrder,
    },
    /// SH coefficients; `basis` when the header or a sidecar records it.
    Sh {
        /// The even maximum SH order whose coefficient count (1, 6, 15, 28, 45, ...) is the number of volumes.
        l_max: usize,
        /// The basis the header (`descrip`) or a JSON sidecar records (tournier07 for MRtrix images); `None`
        /// when unknown.
        basis: Option<ShBasis>,
    },
    /// Peak directions: MRtrix's 3N volumes, DIPY's (X,Y,Z,N,3) `_dirs` or an FSL dtifit eigenvector (`_V1`).
    Peaks,
    /// An RGB colour map (RGB datatype, RGB-vector intent, or 3 volumes named "rgb").
    Rgb,
    /// A single volume (a 3D image, or 4D with one volume).
    Scalar,
    /// Another 4D series (as many volumes as the shape says).
    Series,
}

impl ImageKind {
    /// The name `fascicle info --json` prints: dwi, tensor, sh, peaks, rgb, scalar, volume.
    pub fn name(&self) -> &'static str {
        match self {
            ImageKind::Dwi { .. } => "dwi",
            ImageKind::Tensor { .. } => "tensor",
            ImageKind::Sh { .. } => "sh",
            ImageKind::Peaks => "peaks",
            ImageKind::Rgb => "rgb",
            ImageKind::Scalar => "scalar",
            ImageKind::Series => "volume",
        }
    }
}

/// A classification and the evidence for it.
#[derive(Clone, Debug, PartialEq)]
pub struct Classified {
    /// The kind decided on; when [`Classified::ambiguous`] is not empty, the best guess among its alternatives.
    pub kind: ImageKind,
    /// What decided it, for messages and `info`.
    pub reason: String,
    /// Other kinds the content allows when it did not decide (empty when it did).
    pub ambiguous: Vec<ImageKind>,
}

/// The gradient files beside an image (`x.nii.gz` -> `x.bval`, `x.bvec`), if both exist.
pub fn gradients_beside(path: &Path) -> Option<(PathBuf, PathBuf)> {
    let stem = stem_path(path);
    let (bval, bvec) = (with_ext(&stem, "bval"), with_ext(&stem, "bvec"));
    (bval.is_file() && bvec.is_file()).then_some((bval, bvec))
}

/// `dir/x.nii.gz` -> `dir/x`.
fn stem_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let stem = name.strip_suffix(".gz").unwrap_or(&name);
    let stem = stem.strip_suffix(".nii").unwrap_or(stem);
    path.with_file_name(stem)
}

fn with_ext(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_os_string();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

/// The text of the JSON sidecar beside an image (`x.nii.gz` -> `x.json`), if there is one.
fn sidecar(path: &Path) -> Option<String> {
    std::fs::read_to_string(with_ext(&stem_path(path), "json")).ok()
}

/// The SH basis a sidecar's text records (`"sh_basis": {"convention": ..., "legacy": ...}`, as `fascicle fit`
/// writes it). A small scan for the keys `fascicle fit` and BIDS-style derivatives write, not a general JSON
/// parser.
fn sidecar_basis(text: &str) -> Option<ShBasis> {
    let at = text.find("\"sh_basis\"")?;
    let rest = &text[at..];
    let convention = string_value(rest, "convention")?;
    let legacy = rest
        .find("\"legacy\"")
        .map(|i| rest[i + 8..].trim_start_matches([' ', ':', '\t', '\n']))
        .is_some_and(|v| v.starts_with("true"));
    ShBasis::parse(&convention, legacy).ok()
}

fn string_value(text: &str, key: &str) -> Option<String> {
    let at = text.find(&format!("\"{key}\""))?;
    let rest = text[at + key.len() + 2..].trim_start_matches([' ', ':', '\t', '\n', '\r']);
    let rest = rest.strip_prefix('"')?;
    Some(rest[..rest.find('"')?].to_string())
}

/// Classifies the image at `path` (reading its data only when the header and the files beside it do not
/// decide).
pub fn classify(path: &Path) -> Result<Classified> {
    if super::mif::is_mif(path) {
        return classify_mif(path);
    }
    let header = nifti::read_header(path)?;
    classify_with(path, &header, || nifti::read::<f32>(path).map(|(v, _)| v))
}

/// An MRtrix image: SH in MRtrix's basis (tournier07) and tensors in its element order unless the content says
/// otherwise; a `dw_scheme` marks a DWI series (shown as volumes: the scheme is not a bval/bvec pair).
fn classify_mif(path: &Path) -> Result<Classified> {
    let (vol, h) = super::mif::read::<f32>(path)?;
    Ok(classify_mif_image(&vol, &h))
}

/// [`classify`] of an MRtrix image already read.
pub fn classify_mif_image(vol: &Volume<f32>, h: &super::mif::MifHeader) -> Classified {
    let vols: usize = vol.shape.get(3..).map_or(1, |s| s.iter().product());
    let decided = |kind, reason: &str| Classified { kind, reason: reason.to_string(), ambiguous: vec![] };
    if vols <= 1 {
        return decided(ImageKind::Scalar, "one volume");
    }
    if !h.dw_scheme.is_empty() {
        return decided(ImageKind::Series, "a DWI series (dw_scheme)");
    }
    if vols == 6 {
        let (order, share) = best_tensor_order(vol);
        if share >= 0.5 {
            return decided(ImageKind::Tensor { order }, "6 volumes of positive-definite tensors");
        }
    }
    if let Some(l_max) = sh::l_max_for(vols)
        && positive_first_share(vol) >= 0.99
    {
        let basis = Some(ShBasis::Tournier07 { legacy: false });
        return decided(ImageKind::Sh { l_max, basis }, "SH coefficients of an MRtrix image (tournier07)");
    }
    decided(
        if vols.is_multiple_of(3) && vols != 3 { ImageKind::Peaks } else { ImageKind::Series },
        "volumes of an MRtrix image",
    )
}

/// [`classify`] with the header read and the data behind `data` (called at most once).
pub fn classify_with(path: &Path, h: &NiftiHeader, data: impl FnOnce() -> Result<Volume<f32>>) -> Result<Classified> {
    let decided = |kind, reason: &str| Ok(Classified { kind, reason: reason.to_string(), ambiguous: vec![] });
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let vols: usize = h.shape.get(3..).map_or(1, |s| s.iter().product());
    let four_d = h.shape.len() >= 4 && vols > 1;
    if h.shape.len() == 5 && h.shape[4] == 3 {
        return decided(ImageKind::Peaks, "5D with 3 components: DIPY's peak directions");
    }
    if h.datatype == DT_RGB24 || h.datatype == DT_RGBA32 {
        return decided(ImageKind::Rgb, "RGB datatype");
    }
    if h.intent_code == INTENT_RGB_VECTOR {
        return decided(ImageKind::Rgb, "intent RGB vector");
    }
    if !four_d {
        return decided(ImageKind::Scalar, "one volume");
    }
    if let Some((bval, bvec)) = gradients_beside(path) {
        return decided(ImageKind::Dwi { bval, bvec }, "bval/bvec beside the image");
    }
    // The sidecar is read once, for the basis and the model.
    let side = sidecar(path);
    let recorded = sh::recorded_basis(&h.descrip).or_else(|| side.as_deref().and_then(sidecar_basis));
    let l_max = sh::l_max_for(vols);
    if let (Some(basis), Some(l_max)) = (recorded, l_max) {
        return decided(ImageKind::Sh { l_max, basis: Some(basis) }, "SH basis recorded in the header or sidecar");
    }
    let model = side.as_deref().and_then(|t| string_value(t, "model")).map(|m| m.to_ascii_lowercase());
    if vols == 6 && (h.intent_code == INTENT_SYMMATRIX || matches!(model.as_deref(), Some("dti" | "tensor"))) {
        let vol = data()?;
        let (order, _) = best_tensor_order(&vol);
        return decided(ImageKind::Tensor { order }, "intent symmetric matrix (element order from the content)");
    }
    if vols == 3 && super::peaks::fsl_eigenvector(path) {
        return decided(ImageKind::Peaks, "FSL dtifit eigenvector (_V1, _V2, _V3)");
    }
    let says_peaks = name.contains("peak") || h.intent_name.to_ascii_lowercase().contains("peak");
    if vols.is_multiple_of(3) && (says_peaks || h.intent_code == INTENT_VECTOR) {
        return decided(ImageKind::Peaks, "named or marked as peaks / vectors");
    }
    if vols == 3 && name.contains("rgb") {
        return decided(ImageKind::Rgb, "3 volumes named RGB");
    }
    if vols != 6 && l_max.is_none() {
        return decided(ImageKind::Series, "a series of volumes");
    }
    // The content decides: tensors are positive definite in one element order; SH fields have c00 > 0
    // wherever there is signal; peaks have no sign preference.
    let vol = data()?;
    let sh_share = positive_first_share(&vol);
    if vols == 6 {
        let (order, share) = best_tensor_order(&vol);
        let tensor = ImageKind::Tensor { order };
        let sh2 = ImageKind::Sh { l_max: 2, basis: None };
        return Ok(if share >= 0.8 {
            Classified {
                kind: tensor,
                reason: format!("6 volumes, {:.0} % positive definite in {order:?} order", share * 100.0),
                ambiguous: vec![],
            }
        } else if sh_share >= 0.99 && share < 0.2 {
            Classified {
                kind: sh2,
                reason: "6 volumes, not tensors, c00 > 0 everywhere: l_max 2 SH".into(),
                ambiguous: vec![],
            }
        } else {
            Classified {
                kind: tensor.clone(),
                reason: format!("6 volumes: {:.0} % positive definite at best", share * 100.0),
                ambiguous: vec![tensor, sh2],
            }
        });
    }
    let l_max = l_max.unwrap_or(0);
    let sh = ImageKind::Sh { l_max, basis: None };
    Ok(if sh_share >= 0.99 {
        Classified {
            kind: sh,
            reason: format!("{vols} volumes with c00 > 0 wherever there is signal: SH"),
            ambiguous: vec![],
        }
    } else if vols.is_multiple_of(3) && sh_share < 0.9 {
        Classified {
            kind: ImageKind::Peaks,
            reason: format!("{vols} volumes whose first has both signs: peaks"),
            ambiguous: vec![],
        }
    } else {
        let mut alternatives = vec![sh.clone()];
        if vols.is_multiple_of(3) {
            alternatives.push(ImageKind::Peaks);
        }
        alternatives.push(ImageKind::Series);
        Classified { kind: sh, reason: format!("{vols} volumes, content inconclusive"), ambiguous: alternatives }
    })
}

/// Voxels with any non-zero finite value: the share whose first volume is positive.
fn positive_first_share(vol: &Volume<f32>) -> f64 {
    let (n, c) = (vol.n_voxels(), vol.n_channels());
    let (mut signal, mut positive) = (0usize, 0usize);
    for v in 0..n {
        if (0..c).any(|k| vol.data[v + n * k] != 0.0 && vol.data[v + n * k].is_finite()) {
            signal += 1;
            positive += usize::from(vol.data[v] > 0.0);
        }
    }
    if signal == 0 { 0.0 } else { positive as f64 / signal as f64 }
}

/// The tensor element order under which most voxels with signal are positive definite, and that share.
pub fn best_tensor_order(vol: &Volume<f32>) -> (TensorOrder, f64) {
    let n = vol.n_voxels();
    let signal: Vec<usize> = (0..n).filter(|&v| (0..6).any(|k| vol.data[v + n * k] != 0.0)).collect();
    let share = |order: TensorOrder| {
        if signal.is_empty() {
            return 0.0;
        }
        let s = order.dipy_slots();
        let pd = signal
            .iter()
            .filter(|&&v| {
                let d = |slot: usize| vol.data[v + n * s[slot]] as f64;
                let (xx, xy, yy, xz, yz, zz) = (d(0), d(1), d(2), d(3), d(4), d(5));
                // Sylvester's criterion: leading principal minors positive.
                let m2 = xx * yy - xy * xy;
                let det = xx * (yy * zz - yz * yz) - xy * (xy * zz - yz * xz) + xz * (xy * yz - yy * xz);
                xx > 0.0 && m2 > 0.0 && det > 0.0
            })
            .count();
        pd as f64 / signal.len() as f64
    };
    TensorOrder::ALL
        .into_iter()
        .map(|o| (o, share(o)))
        .fold((TensorOrder::Dipy, -1.0), |best, x| if x.1 > best.1 { x } else { best })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::nifti::{WriteMeta, WriteType};

    fn tensors(order: TensorOrder) -> Volume<f32> {
        // 4x3x2 voxels of anisotropic tensors with off-diagonal terms, a few empty.
        let mut v = Volume::<f32>::zeros(&[4, 3, 2, 6], glam::DMat4::IDENTITY);
        let n = 24;
        for vox in 0..n {
            if vox % 7 == 3 {
                continue;
            }
            let t = vox as f32 * 0.01;
            // DIPY order: xx xy yy xz yz zz.
            let dipy = [1.7e-3 + t * 1e-4, 2e-4, 4e-4 + t * 1e-5, -1e-4, 5e-5, 3e-4];
            for (slot, &src) in order.dipy_slots().iter().enumerate() {
                v.data[vox + n * src] = dipy[slot];
            }
        }
        v
    }

    fn write(dir: &Path, name: &str, v: &Volume<f32>, meta: &WriteMeta) -> PathBuf {
        let p = dir.join(name);
        nifti::write_with(&p, v, WriteType::F32, meta).unwrap();
        p
    }

    /// Each element order of a 6-volume tensor image is told by content alone, and reordering gives DIPY's.
    #[test]
    fn tensor_orders_are_told_by_content() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-classify-t-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let dipy = tensors(TensorOrder::Dipy);
        for order in TensorOrder::ALL {
            let v = tensors(order);
            let p = write(&dir, &format!("t_{order:?}.nii.gz"), &v, &WriteMeta::default());
            let c = classify(&p).unwrap();
            assert_eq!(c.kind, ImageKind::Tensor { order }, "{c:?}");
            assert!(c.ambiguous.is_empty());
            let mut back = v.clone();
            order.to_dipy(&mut back);
            assert_eq!(back.data, dipy.data);
        }
    }

    /// SH counts: 15 volumes with c00 > 0 open as SH (l_max 4), the same count with mixed signs as peaks,
    /// a recorded basis is honoured, "peaks" in the name wins, bval/bvec beside make a DWI, a 3D image is
    /// scalar and a 7-volume image a series.
    #[test]
    fn sh_peaks_dwi_and_others_by_metadata_and_content() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-classify-s-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let mut sh15 = Volume::<f32>::zeros(&[3, 3, 2, 15], glam::DMat4::IDENTITY);
        let n = 18;
        for v in 0..n {
            sh15.data[v] = 0.28;
            for k in 1..15 {
                sh15.data[v + n * k] = ((v * 7 + k * 3) % 11) as f32 * 0.01 - 0.05;
            }
        }
        let p = write(&dir, "odf.nii.gz", &sh15, &WriteMeta::default());
        let c = classify(&p).unwrap();
        assert_eq!(c.kind, ImageKind::Sh { l_max: 4, basis: None }, "{c:?}");
        let mut peaks = sh15.clone();
        for v in 0..n {
            peaks.data[v] = if v % 2 == 0 { 0.7 } else { -0.7 };
        }
        assert_eq!(
            classify(&write(&dir, "five.nii.gz", &peaks, &WriteMeta::default())).unwrap().kind,
            ImageKind::Peaks
        );
        assert_eq!(
            classify(&write(&dir, "csa_peaks.nii.gz", &sh15, &WriteMeta::default())).unwrap().kind,
            ImageKind::Peaks
        );
        let basis = ShBasis::Tournier07 { legacy: false };
        let meta = WriteMeta { descrip: sh::sh_descrip(basis, 4), ..Default::default() };
        let p = write(&dir, "recorded.nii.gz", &peaks, &meta);
        assert_eq!(classify(&p).unwrap().kind, ImageKind::Sh { l_max: 4, basis: Some(basis) });
        // A sidecar, as `fascicle fit csa` writes it.
        let p = write(&dir, "side.nii.gz", &sh15, &WriteMeta::default());
        std::fs::write(
            dir.join("side.json"),
            "{\n  \"model\": \"csa\",\n  \"sh_basis\": { \"convention\": \"descoteaux07\", \"legacy\": true }\n}\n",
        )
        .unwrap();
        assert_eq!(
            classify(&p).unwrap().kind,
            ImageKind::Sh { l_max: 4, basis: Some(ShBasis::Descoteaux07 { legacy: true }) }
        );
        let p = write(&dir, "dwi.nii.gz", &sh15, &WriteMeta::default());
        std::fs::write(dir.join("dwi.bval"), "0 1000").unwrap();
        std::fs::write(dir.join("dwi.bvec"), "0 1\n0 0\n0 0").unwrap();
        assert!(matches!(classify(&p).unwrap().kind, ImageKind::Dwi { .. }));
        let scalar = Volume::<f32>::zeros(&[3, 3, 2], glam::DMat4::IDENTITY);
        assert_eq!(
            classify(&write(&dir, "fa.nii.gz", &scalar, &WriteMeta::default())).unwrap().kind,
            ImageKind::Scalar
        );
        let series = Volume::<f32>::zeros(&[3, 3, 2, 7], glam::DMat4::IDENTITY);
        assert_eq!(classify(&write(&dir, "s.nii.gz", &series, &WriteMeta::default())).unwrap().kind, ImageKind::Series);
    }

    /// Six volumes that are neither tensors nor clearly SH are ambiguous, with both offered.
    #[test]
    fn inconclusive_content_is_marked_ambiguous() {
        let mut v = Volume::<f32>::zeros(&[2, 2, 1, 6], glam::DMat4::IDENTITY);
        let n = 4;
        for vox in 0..n {
            for k in 0..6 {
                v.data[vox + n * k] = if (vox + k) % 2 == 0 { 1.0 } else { -1.0 };
            }
        }
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-classify-a-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let c = classify(&write(&dir, "x.nii", &v, &WriteMeta::default())).unwrap();
        assert_eq!(c.ambiguous.len(), 2, "{c:?}");
    }
}

#[cfg(test)]
mod rgb_tests {
    use super::*;
    use crate::io::nifti::WriteType;

    /// A packed RGB24 image (as nibabel writes `color_fa`) reads as three volumes of its bytes and classifies
    /// as RGB.
    #[test]
    fn rgb24_images_read_as_three_volumes() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-rgb24-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let path = dir.join("color_fa.nii");
        // A u8 image of 6x2x1 holds the 12 bytes of 2x2x1 RGB voxels; its header is then patched to RGB24.
        let bytes: Vec<u8> = vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 10, 20, 30];
        let mut v = Volume::<f32>::zeros(&[6, 2, 1], glam::DMat4::IDENTITY);
        v.data = bytes.iter().map(|&b| b as f32).collect();
        nifti::write(&path, &v, WriteType::U8).unwrap();
        let mut file = std::fs::read(&path).unwrap();
        file[42..44].copy_from_slice(&2i16.to_le_bytes()); // dim[1]
        file[70..72].copy_from_slice(&128i16.to_le_bytes()); // datatype rgb24
        file[72..74].copy_from_slice(&24i16.to_le_bytes()); // bitpix
        std::fs::write(&path, file).unwrap();
        let (img, _) = nifti::read::<f32>(&path).unwrap();
        assert_eq!(img.shape, vec![2, 2, 1, 3]);
        // Channel-major: red of the four voxels, then green, then blue.
        assert_eq!(img.data, vec![255.0, 0.0, 0.0, 10.0, 0.0, 255.0, 0.0, 20.0, 0.0, 0.0, 255.0, 30.0]);
        assert_eq!(classify(&path).unwrap().kind, ImageKind::Rgb);
    }
}
