//! The tracker's checks of a pose on evidence the tracking step does not optimise: the
//! outline agreement can stay high while the pose slides to a wrong one whose outline
//! still finds edges (clutter next to the object, a turn its outline barely shows). Every
//! few frames, when the colours are relearnt from a render at the pose, that render is
//! compared with the frame: its silhouette with the pixels the colour model calls object,
//! and its appearance (colours and interior edges, as hypothesis verification scores
//! them) with the frame's.
//!
//! The appearance threshold was chosen on 234 checks of generated sequences at 10° / 5 cm
//! per frame (docs/tracking.md): poses right by MSSD < 0.1·d scored 0.42 or more in 95 %
//! of checks, poses off by more than 0.3·d under 0.34 in 95 %. (Edges alone, tried first
//! on a slower sequence, fell to ~0.4 for poses 2–4° off; the colours keep it apart.)
//! Left out: checking a re-initialising pose against the colours learnt before the loss
//! refused the true pose (IoU 0.40) once the box had turned a face the colours had not
//! seen.

use super::colour::{ColourModel, Window};
use crate::estimate::verify::{appearance_agreement_where, colour_agreement_where};
use crate::render::RenderOutput;
use image::{GrayImage, RgbImage};

/// How much the object rendered at the pose through `window` alone looks like the frame
/// there, 0–1: the verification's mix of colour and edge agreement over the pixels well
/// inside the render's silhouette. Only for meshes with colours of their own (a texture
/// or vertex colours): a grey render's edges against a photo's were not measured as a
/// test of the pose, so such meshes get no appearance check.
pub fn appearance(render: &RenderOutput, image: &RgbImage, window: Window) -> f64 {
    let (w, h) = window.size();
    let area = (window.x0, window.y0, w, h);
    let edges = appearance_agreement_where(render, image, area, &|_, _| true);
    let colour = colour_agreement_where(render, image, area, &|_, _| true);
    crate::estimate::verify::appearance(edges, colour, crate::estimate::verify::VerifyConfig::default().colour_share)
}

/// IoU of `silhouette` (the pose rendered through `window` alone, the window's size) with
/// the pixels in the window whose foreground probability is over one half.
pub fn silhouette_iou(colours: &ColourModel, image: &RgbImage, silhouette: &GrayImage, window: Window) -> f64 {
    let object = colours.object_bins();
    let (mut both, mut either) = (0usize, 0usize);
    let read = window.each_with_silhouette(image, silhouette, |c, rendered| {
        let coloured = object(&c);
        both += (rendered && coloured) as usize;
        either += (rendered || coloured) as usize;
    });
    if !read || either == 0 {
        0.0
    } else {
        both as f64 / either as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_of_silhouette_and_object_colours() {
        // The colours learnt from the square itself.
        let (img, sil) = crate::track::colour::tests::red_square();
        let all = Window { x0: 0, y0: 0, x1: 40, y1: 40 };
        let mut colours = ColourModel::default();
        assert!(colours.learn(&img, &sil, all, 1.0));
        assert_eq!(silhouette_iou(&colours, &img, &sil, all), 1.0);
        // The silhouette moved half its side to the right: a third of the union is shared.
        let shifted = GrayImage::from_fn(40, 40, |x, y| image::Luma([if (20..40).contains(&x) && (10..30).contains(&y) { 255 } else { 0 }]));
        assert!((silhouette_iou(&colours, &img, &shifted, all) - 1.0 / 3.0).abs() < 1e-9);
        assert_eq!(silhouette_iou(&ColourModel::default(), &img, &GrayImage::new(40, 40), all), 0.0);
        // A window off the image's corner reads the silhouette's rows against its own.
        let part = Window { x0: 5, y0: 8, x1: 35, y1: 33 };
        let sil_part = image::imageops::crop_imm(&sil, 5, 8, 30, 25).to_image();
        assert_eq!(silhouette_iou(&colours, &img, &sil_part, part), 1.0);
        // The shifted silhouette cut at the window's right edge (x 35): 200 shared of 500.
        let sil_shifted = image::imageops::crop_imm(&shifted, 5, 8, 30, 25).to_image();
        assert!((silhouette_iou(&colours, &img, &sil_shifted, part) - 0.4).abs() < 1e-9);
        // A silhouette that is not the window's size measures nothing.
        assert_eq!(silhouette_iou(&colours, &img, &GrayImage::new(10, 10), part), 0.0);
    }
}
