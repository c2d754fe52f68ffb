//! What a generated dataset looks like: sizes, framing, occlusion and appearance.

/// Parameters of a generated scene set. Every random choice derives from `seed`, image by
/// image, so a dataset is reproducible and one image does not depend on the others.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneConfig {
    pub images: usize,
    /// Object instances per image (the caller's objects in turn, repeating when there are
    /// fewer objects than slots). 1–3 is the intended range; at most `MAX_OBJECTS_PER_IMAGE`.
    pub objects_per_image: usize,
    /// With a value above `objects_per_image`, each image holds a count drawn uniformly from
    /// `objects_per_image..=objects_per_image_max` (BOP's real test scenes vary, 2–6
    /// objects a frame in the benchmarks); 0 keeps every image at `objects_per_image`
    /// (and its images exactly as they were before this field).
    #[serde(default)]
    pub objects_per_image_max: usize,
    /// (width, height) in pixels.
    pub image_size: (u32, u32),
    /// Focal length as a multiple of the image width (fx = fy = f·width), drawn per image:
    /// relative, so the field of view does not change with resolution. 0.9 at 640 px wide is
    /// 576 px, close to LINEMOD's Kinect.
    pub focal_range: (f64, f64),
    /// The object's diameter as a fraction of the image height, drawn per instance; sets the
    /// camera distance (objects of any size fill the image alike, which a range in metres
    /// would not do across objects).
    pub fill_range: (f64, f64),
    /// Largest hidden fraction of an instance's silhouette (by other objects and occluders);
    /// placements that hide more are drawn again. At most 0.9, so that every instance is a
    /// BOP'19 target (visible fraction ≥ 0.1).
    pub max_occlusion: f64,
    /// Smallest hidden fraction of every instance: with it above 0, each instance gets
    /// occluders until it hides at least this much (and the image is drawn again when that
    /// fails), for measuring heavily occluded objects. At most `max_occlusion`.
    #[serde(default)]
    pub min_occlusion: f64,
    /// Draw flat coloured discs and polygons in front of parts of the objects.
    pub occluders: bool,
    /// Place each object after the first beside one already placed (their image
    /// footprints touching or overlapping a little), as parts stand against each other on a
    /// bench or in a bin, rather than anywhere in the frame: a box around one then takes in
    /// its neighbours, as a detector's boxes do in real clutter.
    #[serde(default)]
    pub clustered: bool,
    pub appearance: Appearance,
    /// Simulate a stronger render-to-real gap: the templates are renders of the bare mesh
    /// made elsewhere, so here the gap can only widen by degrading the scene more. It
    /// replaces `appearance` by `appearance.harsher()`: raking light, darker ambient, twice
    /// the blur, noise and colour shift.
    pub render_to_real_gap: bool,
    pub seed: u64,
    /// Render and composite at this many times the resolution in each direction, then
    /// average each block down to one pixel, as a camera's pixel integrates the light over
    /// its area: an outline then blends into what is behind it, where at 1 every pixel shows
    /// one surface and outlines move in whole-pixel steps. Masks and depth are each pixel's
    /// centre sample, as BOP renders them. 1 or an odd number up to `MAX_SUPERSAMPLING`.
    #[serde(default = "one")]
    pub supersampling: u32,
    /// What the depth camera measures of the scene (a Kinect-class sensor by default; see
    /// `depth::sensor`), with a flat background behind the objects. `SensorModel::exact()`
    /// keeps the renderer's depth.
    #[serde(default)]
    pub depth_sensor: crate::depth::sensor::SensorModel,
}

fn one() -> u32 {
    1
}

pub const MAX_SUPERSAMPLING: u32 = 5;

pub const MAX_OBJECTS_PER_IMAGE: usize = 8;

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            images: 10,
            objects_per_image: 2,
            objects_per_image_max: 0,
            image_size: (640, 480),
            focal_range: (0.85, 1.05),
            fill_range: (0.10, 0.40),
            max_occlusion: 0.3,
            min_occlusion: 0.0,
            occluders: true,
            clustered: false,
            appearance: Appearance::default(),
            render_to_real_gap: false,
            seed: 1,
            supersampling: 1,
            depth_sensor: Default::default(),
        }
    }
}

/// Lighting and image degradations, each drawn per image uniformly from its range.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Appearance {
    /// Largest angle in degrees between the light and the camera's viewing direction
    /// (0 is a headlight; near 90° rakes across the objects).
    pub light_angle_deg: f64,
    pub light_intensity: (f32, f32),
    pub ambient: (f32, f32),
    /// Gaussian blur standard deviation, pixels.
    pub blur_sigma: (f64, f64),
    /// Additive sensor noise standard deviation, grey levels.
    pub noise_sigma: (f64, f64),
    /// Largest per-channel gain deviation from 1 (white balance, exposure).
    pub color_gain: f64,
    /// Largest per-channel offset, grey levels.
    pub color_offset: f64,
    /// JPEG quality the photo is stored at, drawn per image (1–100); `None`: lossless.
    #[serde(default)]
    pub jpeg_quality: Option<(u8, u8)>,
    /// Largest per-channel gain deviation of an object's print from its mesh's texture, a
    /// colour field varying smoothly across the object (`eval::degrade::PrintDrift`).
    #[serde(default)]
    pub print_gain: f64,
    /// Largest misregistration of an object's print against its shape, pixels per axis.
    #[serde(default)]
    pub print_shift_px: f64,
}

impl Default for Appearance {
    fn default() -> Self {
        Self {
            light_angle_deg: 45.0,
            light_intensity: (0.5, 0.9),
            ambient: (0.2, 0.4),
            blur_sigma: (0.0, 0.8),
            noise_sigma: (1.0, 3.0),
            color_gain: 0.08,
            color_offset: 6.0,
            jpeg_quality: None,
            print_gain: 0.0,
            print_shift_px: 0.0,
        }
    }
}

impl Appearance {
    /// What `render_to_real_gap` uses: light up to 80° off the viewing direction with half
    /// the ambient (hard shading the templates never show), twice the blur, noise and
    /// colour shift (lower bounds raised too, so no image escapes clean), JPEG at quality
    /// 50–85, and prints that drift from the texture by up to 15 % and 1 pixel.
    pub fn harsher(&self) -> Self {
        let double = |(lo, hi): (f64, f64)| (lo.max(hi * 0.5) * 2.0, hi * 2.0);
        Self {
            light_angle_deg: self.light_angle_deg.max(80.0),
            light_intensity: (self.light_intensity.0, self.light_intensity.1 * 1.2),
            ambient: (self.ambient.0 * 0.5, self.ambient.1 * 0.5),
            blur_sigma: double(self.blur_sigma),
            noise_sigma: double(self.noise_sigma),
            color_gain: self.color_gain * 2.0,
            color_offset: self.color_offset * 2.0,
            jpeg_quality: Some(self.jpeg_quality.map_or((50, 85), |(lo, hi)| (lo.min(50), hi.min(85)))),
            print_gain: (self.print_gain * 2.0).max(0.15),
            print_shift_px: (self.print_shift_px * 2.0).max(1.0),
        }
    }
}

impl SceneConfig {
    /// The appearance images are actually drawn with.
    pub fn effective_appearance(&self) -> Appearance {
        if self.render_to_real_gap {
            self.appearance.harsher()
        } else {
            self.appearance.clone()
        }
    }

    /// How many instances an image holds: `objects_per_image`, or a uniform draw up to
    /// `objects_per_image_max` (drawing from `rng` only then, so fixed-count images keep
    /// their random streams).
    pub fn objects_in_image(&self, rng: &mut crate::mesh::procedural::Rng) -> usize {
        if self.objects_per_image_max > self.objects_per_image {
            let span = (self.objects_per_image_max - self.objects_per_image + 1) as u64;
            self.objects_per_image + (rng.next_u64() % span) as usize
        } else {
            self.objects_per_image
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        let range = |name: &str, (lo, hi): (f64, f64), min: f64, max: f64| {
            if lo.is_finite() && hi.is_finite() && min <= lo && lo <= hi && hi <= max {
                Ok(())
            } else {
                Err(format!("{name} ({lo}, {hi}) must satisfy {min} ≤ lo ≤ hi ≤ {max}"))
            }
        };
        if !(1..=MAX_OBJECTS_PER_IMAGE).contains(&self.objects_per_image) {
            return Err(format!("objects_per_image must be 1–{MAX_OBJECTS_PER_IMAGE}, got {}", self.objects_per_image));
        }
        if self.objects_per_image_max != 0 && !(self.objects_per_image..=MAX_OBJECTS_PER_IMAGE).contains(&self.objects_per_image_max) {
            return Err(format!("objects_per_image_max must be 0 (fixed) or {}–{MAX_OBJECTS_PER_IMAGE} (at least objects_per_image), got {}", self.objects_per_image, self.objects_per_image_max));
        }
        let (w, h) = self.image_size;
        if w < 16 || h < 16 {
            return Err(format!("image size {w}x{h} is too small (at least 16x16)"));
        }
        range("focal_range", self.focal_range, 0.05, 20.0)?;
        // Past 0.9 of the height a rotated object no longer fits inside the frame.
        range("fill_range", self.fill_range, 0.01, 0.9)?;
        range("max_occlusion", (self.max_occlusion, self.max_occlusion), 0.0, 0.9)?;
        range("(min_occlusion, max_occlusion)", (self.min_occlusion, self.max_occlusion), 0.0, 0.9)?;
        if self.supersampling == 0 || self.supersampling > MAX_SUPERSAMPLING || self.supersampling.is_multiple_of(2) {
            return Err(format!("supersampling must be 1 or an odd number up to {MAX_SUPERSAMPLING} (each pixel needs a centre sample), got {}", self.supersampling));
        }
        if self.min_occlusion > 0.0 && !self.occluders {
            return Err("min_occlusion needs occluders".into());
        }
        let a = &self.appearance;
        range("light_angle_deg", (a.light_angle_deg, a.light_angle_deg), 0.0, 89.0)?;
        range("light_intensity", (a.light_intensity.0 as f64, a.light_intensity.1 as f64), 0.0, 10.0)?;
        range("ambient", (a.ambient.0 as f64, a.ambient.1 as f64), 0.0, 10.0)?;
        range("blur_sigma", a.blur_sigma, 0.0, 20.0)?;
        range("noise_sigma", a.noise_sigma, 0.0, 100.0)?;
        range("color_gain", (a.color_gain, a.color_gain), 0.0, 0.9)?;
        range("color_offset", (a.color_offset, a.color_offset), 0.0, 128.0)?;
        if let Some((lo, hi)) = a.jpeg_quality {
            range("jpeg_quality", (lo as f64, hi as f64), 1.0, 100.0)?;
        }
        range("print_gain", (a.print_gain, a.print_gain), 0.0, 0.5)?;
        range("print_shift_px", (a.print_shift_px, a.print_shift_px), 0.0, 10.0)
    }
}
