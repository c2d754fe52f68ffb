//! A picture of what the detector found: each detection's mask outline and box over the
//! image, one colour per object (brighter for higher scores).

use crate::detect::DetectReport;
use crate::render::overlay::draw_line;
use image::RgbImage;

const PALETTE: [[u8; 3]; 6] = [[0, 255, 0], [255, 64, 255], [0, 200, 255], [255, 200, 0], [255, 80, 80], [160, 120, 255]];

pub fn draw(image: &RgbImage, report: &DetectReport) -> RgbImage {
    let mut out = image.clone();
    let mut colours: Vec<&str> = Vec::new();
    for d in &report.detections {
        let place = colours.iter().position(|&c| c == d.object_id).unwrap_or_else(|| {
            colours.push(&d.object_id);
            colours.len() - 1
        });
        let colour = PALETTE[place % PALETTE.len()];
        let m = &d.mask;
        let (w, h) = m.dimensions();
        for y in 0..h {
            for x in 0..w {
                let inside = |xx: i64, yy: i64| xx >= 0 && yy >= 0 && xx < w as i64 && yy < h as i64 && m.get_pixel(xx as u32, yy as u32)[0] > 0;
                let (xi, yi) = (x as i64, y as i64);
                if inside(xi, yi) && !(inside(xi - 1, yi) && inside(xi + 1, yi) && inside(xi, yi - 1) && inside(xi, yi + 1)) {
                    out.put_pixel(x, y, image::Rgb(colour));
                }
            }
        }
        let [x, y, bw, bh] = d.bbox;
        let corners = [(x, y), (x + bw, y), (x + bw, y + bh), (x, y + bh)];
        for i in 0..4 {
            draw_line(&mut out, corners[i], corners[(i + 1) % 4], 0, colour);
        }
    }
    out
}
