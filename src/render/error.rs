//! One error type for everything the renderer can refuse or fail at.

/// Why a render (or creating a renderer) failed. Bad inputs are reported here rather than
/// panicking inside wgpu, whose default reaction to a validation error is to abort.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no GPU adapter found (backends tried: {tried}). On a machine without a GPU install \
         Mesa's software Vulkan driver (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers`, \
         check with `vulkaninfo --summary`), or choose a backend with WGPU_BACKEND=vulkan|gl"
    )]
    NoAdapter { tried: String },
    #[error("could not open the GPU device on adapter {adapter}: {message}")]
    RequestDevice { adapter: String, message: String },
    #[error("invalid intrinsics: {0}")]
    InvalidIntrinsics(String),
    #[error("image size {width}x{height} exceeds this device's limit of {max} pixels per side")]
    TooLarge { width: u32, height: u32, max: u32 },
    #[error("invalid pose: {0}")]
    InvalidPose(String),
    #[error("invalid render options: {0}")]
    InvalidOptions(String),
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error("reading the rendered image back failed: {0}")]
    Readback(String),
}
