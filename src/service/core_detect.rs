//! The core's detection: find the named objects (or every stored one) in an image, for the
//! Detect call and for an Estimate that names objects instead of giving detections.
//! Blocking, like every core call.

use super::core::Core;
use super::detect_requests::{check_objects, DetectRequest, DetectResponse};
use super::error::ServiceError;
use super::wire::decode_image;
use crate::detect::{check_options, detect, DetectError, DetectOptions, DetectReport, Target};
use crate::geometry::Intrinsics;
use image::RgbImage;
use std::time::Instant;

impl Core {
    pub fn detect(&self, req: &DetectRequest, deadline: Option<Instant>) -> Result<DetectResponse, ServiceError> {
        let t0 = Instant::now();
        req.check_limits()?;
        let (image, k) = decode_image(&req.image, &req.intrinsics)?;
        let depth = req.depth.as_ref().map(|d| d.decode(k.width, k.height)).transpose()?;
        let report = self.run_detector((&image, depth.as_ref()), &k, &req.objects, &req.options, deadline)?;
        Ok(DetectResponse::new(report, t0))
    }

    /// Detects `objects` (empty: every object in the store) in a decoded image.
    pub(super) fn run_detector(
        &self,
        (image, depth): (&RgbImage, Option<&crate::depth::DepthImage>),
        k: &Intrinsics,
        objects: &[String],
        options: &DetectOptions,
        deadline: Option<Instant>,
    ) -> Result<DetectReport, ServiceError> {
        check_options(options).map_err(|e| ServiceError::invalid(format!("options: {e}")))?;
        check_objects(objects)?;
        let ids = if objects.is_empty() { self.every_object()? } else { unique(objects) };
        // Every object must exist before any work starts.
        let models = ids.iter().map(|id| self.load(id)).collect::<Result<Vec<_>, _>>()?;
        // Objects stored before the detector existed get their templates now (about 2 s,
        // kept with the cached object; `b2tf objects upgrade` stores them).
        let shapes = models
            .iter()
            .map(|m| m.shape_model_or_build(&self.pool).map_err(|e| ServiceError::internal(format!("object {:?}: building its detector templates: {e}", m.object_id))))
            .collect::<Result<Vec<_>, _>>()?;
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return Err(ServiceError::new(super::error::ErrorKind::DeadlineExceeded, "deadline passed before the search started"));
        }
        let targets: Vec<Target> = models.iter().zip(&shapes).map(|(m, s)| Target { id: &m.object_id, shape: s, mesh: &m.mesh }).collect();
        let report = tracing::info_span!("detect", objects = targets.len()).in_scope(|| detect(image, depth, k, &targets, options, &self.pool));
        let report = report.map_err(|e| match e {
            DetectError::BadInput(m) => ServiceError::invalid(format!("options: {m}")),
            e @ DetectError::Render { .. } => ServiceError::internal(e.to_string()),
        })?;
        tracing::debug!(detections = report.detections.len(), ms = report.timings.total_ms, "detected");
        Ok(report)
    }

    /// The ids of every stored object, refused when there are none or too many to search
    /// in one request.
    fn every_object(&self) -> Result<Vec<String>, ServiceError> {
        let ids: Vec<String> = self.list_objects()?.into_iter().map(|o| o.id).collect();
        if ids.is_empty() {
            return Err(ServiceError::invalid(format!("objects: none given and the store {} holds no object; onboard one first", self.store_url())));
        }
        if ids.len() > crate::limits::MAX_DETECT_OBJECTS {
            return Err(ServiceError::invalid(format!(
                "objects: none given and the store holds {} objects, over the limit of {} searched in one request; name the objects",
                ids.len(),
                crate::limits::MAX_DETECT_OBJECTS
            )));
        }
        Ok(ids)
    }
}

/// The ids in their first order, each once.
fn unique(ids: &[String]) -> Vec<String> {
    let mut seen = std::collections::HashSet::new();
    ids.iter().filter(|id| seen.insert(id.as_str())).cloned().collect()
}
