//! Several masks for one box rather than one guess. A box from the caller's detector says
//! where the object is, not which of its pixels are the object: on real clutter one graph
//! cut takes in an occluder, a neighbour of the same colour or the table's edge, and
//! everything downstream trusts it. So a box becomes a few proposals, each from another
//! source, and the estimator's multi-mask selection decides among their poses with
//! evidence no proposal made (the box itself, the photo): `estimate::from_box`.
//!
//! Sources plug in through [`ProposalSource`]; depth proposals are the next to come.

use super::instances::mask_iou;
use super::pixel_box::PixelBox;
use super::segment::{ellipse_in_box, segment_box, Method, SegmentConfig};
use super::OBJECT;
use image::{GrayImage, RgbImage};

/// Where a proposal came from (reported with the answer's diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProposalKind {
    /// The graph cut with the default settings (what a box gave before proposals).
    Cut,
    /// A graph cut that pays more for a label change: fewer, larger regions, so a part
    /// with a printed face stays whole where the default cut keeps only one colour.
    SmoothCut,
    /// A graph cut that learns the background from a ring as wide as the box: a
    /// neighbour of the object's colour that fills the narrow ring no longer looks like
    /// the background, but one that lies farther out does.
    WideRingCut,
    /// The ellipse inscribed in the box: no colour at all, so nothing clutter can mislead.
    Ellipse,
    /// The whole box: a boxy part seen square-on fills it, where a cut keeps only the faces
    /// that differ from the table.
    Fill,
    /// The silhouette of a pose estimated from the other proposals, inside the box.
    Pose,
}

impl std::fmt::Display for ProposalKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ProposalKind::Cut => "cut",
            ProposalKind::SmoothCut => "smooth-cut",
            ProposalKind::WideRingCut => "wide-ring-cut",
            ProposalKind::Ellipse => "ellipse",
            ProposalKind::Fill => "fill",
            ProposalKind::Pose => "pose",
        })
    }
}

/// One candidate mask of the object in a box.
#[derive(Clone, Debug)]
pub struct Proposal {
    /// Image-sized, 255 = object, never empty, never outside the box.
    pub mask: GrayImage,
    pub kind: ProposalKind,
}

/// A way of turning a box into a mask. `None`: this source has nothing to offer here (a
/// cut that collapsed); the others still do.
pub trait ProposalSource: Send + Sync {
    fn kind(&self) -> ProposalKind;
    fn propose(&self, image: &RgbImage, b: &PixelBox) -> Option<GrayImage>;
}

/// A graph cut with its own settings; a collapsed cut proposes nothing (the ellipse is a
/// source of its own).
pub struct CutSource {
    pub kind: ProposalKind,
    pub config: SegmentConfig,
}

impl ProposalSource for CutSource {
    fn kind(&self) -> ProposalKind {
        self.kind
    }

    fn propose(&self, image: &RgbImage, b: &PixelBox) -> Option<GrayImage> {
        let s = segment_box(image, b, &self.config);
        (s.method == Method::GraphCut).then_some(s.mask)
    }
}

pub struct EllipseSource;

impl ProposalSource for EllipseSource {
    fn kind(&self) -> ProposalKind {
        ProposalKind::Ellipse
    }

    fn propose(&self, image: &RgbImage, b: &PixelBox) -> Option<GrayImage> {
        Some(ellipse_in_box(image.width(), image.height(), b))
    }
}

pub struct FillSource;

impl ProposalSource for FillSource {
    fn kind(&self) -> ProposalKind {
        ProposalKind::Fill
    }

    fn propose(&self, image: &RgbImage, b: &PixelBox) -> Option<GrayImage> {
        Some(b.filled(image.width(), image.height()))
    }
}

/// Which sources a box gets, and when two proposals are the same.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProposalConfig {
    pub cut: bool,
    pub smooth_cut: bool,
    pub wide_ring_cut: bool,
    pub ellipse: bool,
    pub fill: bool,
    /// A proposal overlapping an earlier one by at least this IoU adds nothing and is
    /// dropped (its pose would be the same).
    pub same_iou: f64,
}

impl Default for ProposalConfig {
    fn default() -> Self {
        // The three cuts: on real frames they gained over the one cut for about its time;
        // the ellipse gained no more there and doubled the time on generated scenes
        // (docs/estimation.md, "Several proposals per box").
        Self { cut: true, smooth_cut: true, wide_ring_cut: true, ellipse: false, fill: false, same_iou: 0.9 }
    }
}

impl std::str::FromStr for ProposalConfig {
    type Err = String;
    /// A comma-separated list of sources: `cut,smooth-cut,wide-ring-cut,ellipse,fill`.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut cfg = Self { cut: false, smooth_cut: false, wide_ring_cut: false, ellipse: false, fill: false, ..Self::default() };
        for name in s.split(',').map(str::trim) {
            let on = match name {
                "cut" => &mut cfg.cut,
                "smooth-cut" => &mut cfg.smooth_cut,
                "wide-ring-cut" => &mut cfg.wide_ring_cut,
                "ellipse" => &mut cfg.ellipse,
                "fill" => &mut cfg.fill,
                other => return Err(format!("box proposal source {other:?}: expected cut, smooth-cut, wide-ring-cut, ellipse or fill")),
            };
            *on = true;
        }
        Ok(cfg)
    }
}

impl ProposalConfig {
    /// Only the default cut: one mask per box, as before proposals.
    pub fn single() -> Self {
        Self { cut: true, smooth_cut: false, wide_ring_cut: false, ellipse: false, fill: false, ..Self::default() }
    }

    /// The sources switched on after the first, None where there is no other.
    pub fn after_first(&self) -> Option<ProposalConfig> {
        let mut rest = self.clone();
        let first = [&mut rest.cut, &mut rest.smooth_cut, &mut rest.wide_ring_cut, &mut rest.ellipse, &mut rest.fill].into_iter().find(|on| **on)?;
        *first = false;
        (rest.cut || rest.smooth_cut || rest.wide_ring_cut || rest.ellipse || rest.fill).then_some(rest)
    }

    /// The sources switched on, in the order their proposals are listed.
    pub fn sources(&self) -> Vec<Box<dyn ProposalSource>> {
        let base = SegmentConfig::default();
        let mut out: Vec<Box<dyn ProposalSource>> = Vec::new();
        if self.cut {
            out.push(Box::new(CutSource { kind: ProposalKind::Cut, config: base.clone() }));
        }
        if self.smooth_cut {
            out.push(Box::new(CutSource { kind: ProposalKind::SmoothCut, config: SegmentConfig { smoothness: 4.0 * base.smoothness, ..base.clone() } }));
        }
        if self.wide_ring_cut {
            out.push(Box::new(CutSource { kind: ProposalKind::WideRingCut, config: SegmentConfig { ring: 1.0, ..base.clone() } }));
        }
        if self.ellipse {
            out.push(Box::new(EllipseSource));
        }
        if self.fill {
            out.push(Box::new(FillSource));
        }
        out
    }
}

/// The proposals for box `b` (already clipped to `image`), duplicates dropped; never
/// empty: where every source declines, the inscribed ellipse.
pub fn propose(image: &RgbImage, b: &PixelBox, cfg: &ProposalConfig) -> Vec<Proposal> {
    let mut kept = proposed(image, b, cfg, &[]);
    if kept.is_empty() {
        kept.push(Proposal { mask: ellipse_in_box(image.width(), image.height(), b), kind: ProposalKind::Ellipse });
    }
    kept
}

/// The first source's proposal for box `b`, and the sources still to try after it (made
/// by [`more_proposals`] where the estimator asks: `EstimateConfig::sure_proposal_iou`);
/// where the first source declines or is the only one, every proposal at once
/// ([`propose`]) and none to come.
pub fn propose_first(image: &RgbImage, b: &PixelBox, cfg: &ProposalConfig) -> (Vec<Proposal>, Option<ProposalConfig>) {
    let sources = cfg.sources();
    if let (Some(first), Some(rest)) = (sources.first(), cfg.after_first()) {
        if let Some(mask) = first.propose(image, b).filter(|m| m.as_raw().contains(&OBJECT)) {
            return (vec![Proposal { mask, kind: first.kind() }], Some(rest));
        }
    }
    (propose(image, b, cfg), None)
}

/// The proposals of `rest`'s sources for box `b`, those within `same_iou` of one another
/// or of an `earlier` mask dropped; empty where every source declines.
pub fn more_proposals(image: &RgbImage, b: &PixelBox, rest: &ProposalConfig, earlier: &[&GrayImage]) -> Vec<Proposal> {
    proposed(image, b, rest, earlier)
}

/// Every source's proposal, each source on its own thread, in the sources' order; empty
/// ones and those within `same_iou` of an earlier one (or of `earlier`) dropped.
fn proposed(image: &RgbImage, b: &PixelBox, cfg: &ProposalConfig, earlier: &[&GrayImage]) -> Vec<Proposal> {
    let sources = cfg.sources();
    let found: Vec<Proposal> = std::thread::scope(|s| {
        let handles: Vec<_> = sources.iter().map(|src| s.spawn(move || src.propose(image, b).map(|mask| Proposal { mask, kind: src.kind() }))).collect();
        handles.into_iter().filter_map(|h| h.join().ok().flatten()).collect()
    });
    let mut kept: Vec<Proposal> = Vec::new();
    for p in found {
        let same = |m: &GrayImage| mask_iou(m, &p.mask) >= cfg.same_iou;
        if !p.mask.as_raw().contains(&OBJECT) || kept.iter().any(|k| same(&k.mask)) || earlier.iter().any(|m| same(m)) {
            continue;
        }
        kept.push(p);
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    /// A dark disc on a light background, and a second disc of the same colour reaching
    /// into the box from the right: the cuts see two colours, the ellipse none.
    fn scene() -> (RgbImage, PixelBox) {
        let image = RgbImage::from_fn(120, 80, |x, y| {
            let d = |cx: f64, cy: f64| ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
            if d(50.0, 40.0) < 20.0 || d(85.0, 40.0) < 15.0 {
                Rgb([40, 40, 160])
            } else {
                Rgb([220, 210, 200])
            }
        });
        (image, PixelBox { x0: 28, y0: 18, x1: 74, y1: 63 })
    }

    #[test]
    fn a_box_gets_several_distinct_proposals_inside_it() {
        let (image, b) = scene();
        let ps = propose(&image, &b, &ProposalConfig { ellipse: true, ..ProposalConfig::default() });
        assert!(ps.len() >= 2, "{:?}", ps.iter().map(|p| p.kind).collect::<Vec<_>>());
        assert_eq!(ps[0].kind, ProposalKind::Cut);
        assert!(ps.iter().any(|p| p.kind == ProposalKind::Ellipse));
        for p in &ps {
            assert!(p.mask.enumerate_pixels().all(|(x, y, v)| v[0] == 0 || b.contains(x, y)), "{} leaves the box", p.kind);
        }
        for (i, a) in ps.iter().enumerate() {
            for c in &ps[i + 1..] {
                assert!(mask_iou(&a.mask, &c.mask) < 0.9, "{} and {} are the same", a.kind, c.kind);
            }
        }
    }

    #[test]
    fn single_is_the_one_cut_and_nothing_declined_leaves_the_ellipse() {
        let (image, b) = scene();
        let one = propose(&image, &b, &ProposalConfig::single());
        assert_eq!(one.iter().map(|p| p.kind).collect::<Vec<_>>(), vec![ProposalKind::Cut]);
        // A flat image: every cut collapses, and only the ellipse is left.
        let flat = RgbImage::from_pixel(120, 80, Rgb([90, 90, 90]));
        let none: ProposalConfig = "cut,smooth-cut,wide-ring-cut".parse().unwrap();
        let ps = propose(&flat, &b, &none);
        assert_eq!(ps.iter().map(|p| p.kind).collect::<Vec<_>>(), vec![ProposalKind::Ellipse]);
    }

    #[test]
    fn sources_are_named_in_a_list_and_unknown_ones_refused() {
        let cfg: ProposalConfig = "fill, ellipse".parse().unwrap();
        assert_eq!(cfg.sources().iter().map(|s| s.kind()).collect::<Vec<_>>(), vec![ProposalKind::Ellipse, ProposalKind::Fill]);
        let (image, b) = scene();
        let ps = propose(&image, &b, &"fill".parse().unwrap());
        assert_eq!(ps[0].mask.as_raw().iter().filter(|&&v| v == OBJECT).count() as u64, b.area());
        assert_eq!("cut,grabcut".parse::<ProposalConfig>().unwrap_err(), "box proposal source \"grabcut\": expected cut, smooth-cut, wide-ring-cut, ellipse or fill");
        assert_eq!(ProposalConfig::default().sources().iter().map(|s| s.kind()).collect::<Vec<_>>(), vec![ProposalKind::Cut, ProposalKind::SmoothCut, ProposalKind::WideRingCut]);
    }

    #[test]
    fn the_first_proposal_comes_alone_with_the_sources_still_to_try() {
        let (image, b) = scene();
        let cfg: ProposalConfig = "cut,wide-ring-cut,ellipse".parse().unwrap();
        let rest = cfg.after_first().unwrap();
        assert_eq!(rest.sources().iter().map(|s| s.kind()).collect::<Vec<_>>(), vec![ProposalKind::WideRingCut, ProposalKind::Ellipse]);
        assert!(ProposalConfig::single().after_first().is_none());
        let (first, later) = propose_first(&image, &b, &cfg);
        assert_eq!((first.len(), first[0].kind, later.as_ref()), (1, ProposalKind::Cut, Some(&rest)));
        // The later ones: none the same as the first, and the first itself dropped as one.
        let more = more_proposals(&image, &b, &rest, &[&first[0].mask]);
        assert!(!more.is_empty() && more.iter().all(|p| p.kind != ProposalKind::Cut && mask_iou(&p.mask, &first[0].mask) < 0.9));
        let again = more_proposals(&image, &b, &"cut".parse().unwrap(), &[&first[0].mask]);
        assert!(again.is_empty(), "the cut made again is the first");
        // A first source that declines (a flat image): every proposal at once, none to come.
        let flat = RgbImage::from_pixel(120, 80, Rgb([90, 90, 90]));
        let (all, later) = propose_first(&flat, &b, &cfg);
        assert_eq!((all.iter().map(|p| p.kind).collect::<Vec<_>>(), later), (vec![ProposalKind::Ellipse], None));
    }
}
