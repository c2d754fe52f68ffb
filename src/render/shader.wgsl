// One pass writes shaded colour and metric depth. Depth goes to a colour target (not read
// back from the depth buffer) because the GL backend cannot copy depth textures; it is an
// R32Uint target holding the f32's bits, because R32Float is not renderable on plain GLES.

struct Frame {
    clip_from_obj: mat4x4<f32>,
    cam_from_obj: mat4x4<f32>,
    // xyz: unit direction towards the light, camera frame.
    light_dir: vec4<f32>,
    // rgb: linear override albedo; w: 1 to use it, 0 not.
    override_color: vec4<f32>,
    // x: ambient, y: light intensity, z: use texture (0/1), w: use vertex colours (0/1).
    params: vec4<f32>,
};

struct Material {
    // Linear RGBA, as glTF's baseColorFactor.
    base_color: vec4<f32>,
    // x: 1 if the material has a texture and the mesh has UVs.
    flags: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(1) @binding(0) var<uniform> material: Material;
@group(1) @binding(1) var albedo_tex: texture_2d<f32>;
@group(1) @binding(2) var albedo_sampler: sampler;

struct VsIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    // Linear RGB (converted from sRGB on upload); white when the mesh has none.
    @location(2) color: vec3<f32>,
    // Already flipped to texture convention (row 0 at v = 0).
    @location(3) uv: vec2<f32>,
};

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) color: vec3<f32>,
    @location(2) uv: vec2<f32>,
    // Camera z; perspective-correct interpolation makes it the true z of the surface point.
    @location(3) cam_z: f32,
};

struct FsOut {
    @location(0) color: vec4<f32>,
    // bitcast of the camera z (f32).
    @location(1) depth_bits: u32,
};

@vertex
fn vs_main(v: VsIn) -> VsOut {
    let p = vec4<f32>(v.position, 1.0);
    var out: VsOut;
    out.clip = frame.clip_from_obj * p;
    out.cam_z = (frame.cam_from_obj * p).z;
    out.normal = (frame.cam_from_obj * vec4<f32>(v.normal, 0.0)).xyz;
    out.color = v.color;
    out.uv = v.uv;
    return out;
}

@fragment
fn fs_main(f: VsOut) -> FsOut {
    // Sampled unconditionally (textureSample must run in uniform control flow); materials
    // without a texture bind a white 1x1 one, and the weight selects it away anyway.
    let texel = textureSample(albedo_tex, albedo_sampler, f.uv).rgb;
    let tex_w = frame.params.z * material.flags.x;
    var albedo = material.base_color.rgb * mix(vec3<f32>(1.0), texel, tex_w);
    albedo = albedo * mix(vec3<f32>(1.0), f.color, frame.params.w);
    albedo = mix(albedo, frame.override_color.rgb, frame.override_color.w);

    // Two-sided: CAD meshes have inconsistent winding, so |N·L|. A degenerate normal gets a
    // camera-facing one instead of NaN.
    let len = length(f.normal);
    let n = select(vec3<f32>(0.0, 0.0, -1.0), f.normal / len, len > 1e-12);
    let lambert = abs(dot(n, frame.light_dir.xyz));
    let shade = albedo * (frame.params.x + frame.params.y * lambert);

    var out: FsOut;
    out.color = vec4<f32>(clamp(shade, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
    out.depth_bits = bitcast<u32>(f.cam_z);
    return out;
}
