//! What a render should look like; independent of any GPU state.

use super::RenderError;

/// Shading and clipping settings for one render. Colours given here are sRGB in 0..1 (what
/// appears in the output image), except where a field says otherwise.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Direction from the surface towards the light, in the camera frame (x right, y down,
    /// z forward). Lighting is two-sided, so the sign does not matter. Need not be unit length.
    pub light_dir: [f32; 3],
    /// Weight of the directional (Lambert) term.
    pub light_intensity: f32,
    /// Weight of the constant term.
    pub ambient: f32,
    /// Output RGB of pixels the mesh does not cover (written exactly, not shaded).
    pub background: [u8; 3],
    /// Multiply by the part's texture where the mesh has UVs and the material a texture.
    pub use_texture: bool,
    /// Multiply by the mesh's per-vertex colours where it has them.
    pub use_vertex_colors: bool,
    /// Replace base colour × texture × vertex colour by this sRGB colour (e.g. a uniform grey
    /// for appearance-free renders). Lighting still applies.
    pub override_color: Option<[f32; 3]>,
    /// Near and far clip distances in metres (camera z). `None` derives them from the
    /// mesh's bounding sphere at this pose, which never clips the object.
    pub clip_range: Option<(f64, f64)>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            // A headlight: the light sits at the camera, so every visible face is lit.
            light_dir: [0.0, 0.0, -1.0],
            light_intensity: 0.7,
            ambient: 0.3,
            background: [0, 0, 0],
            use_texture: true,
            use_vertex_colors: true,
            override_color: None,
            clip_range: None,
        }
    }
}

impl RenderOptions {
    /// Untextured, uncoloured renders in a uniform grey (shape only).
    pub fn grey() -> Self {
        Self { override_color: Some([0.7, 0.7, 0.7]), ..Self::default() }
    }

    pub(crate) fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::InvalidOptions(m));
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        if !finite(&self.light_dir) {
            return bad(format!("light direction {:?} is not finite", self.light_dir));
        }
        if !finite(&[self.light_intensity, self.ambient]) {
            return bad(format!("light intensity {} / ambient {} not finite", self.light_intensity, self.ambient));
        }
        if let Some(c) = self.override_color {
            if !finite(&c) {
                return bad(format!("override colour {c:?} is not finite"));
            }
        }
        if let Some((n, f)) = self.clip_range {
            if !(n.is_finite() && f.is_finite() && n > 0.0 && f > n) {
                return bad(format!("clip range ({n}, {f}) must satisfy 0 < near < far"));
            }
        }
        Ok(())
    }
}
