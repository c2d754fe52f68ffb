//! `POST /v1/objects` as `multipart/form-data`, for clients that upload files as they are
//! (curl -F, browsers, requests): the same `OnboardRequest` as the JSON body, without
//! base64. Parts: `object_id`, `format` (else from the mesh file's extension), `units`,
//! `replace`, `level`, `in_plane`, `pca`, `descriptors` as text; the mesh file as `mesh`; each file it
//! refers to (MTL, textures, glTF buffers) as a `resource` part named by its file name.

use super::error::{ErrorKind, ServiceError};
use super::requests::{MeshInput, OnboardOptions, OnboardRequest, ResourceInput};
use crate::limits::MAX_MULTIPART_PARTS;
use axum::extract::multipart::{Multipart, MultipartError};

fn part_error(e: MultipartError) -> ServiceError {
    let kind = if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE { ErrorKind::TooLarge } else { ErrorKind::InvalidArgument };
    ServiceError::new(kind, format!("multipart body: {}", e.body_text()))
}

fn number<T: std::str::FromStr>(name: &str, text: &str) -> Result<T, ServiceError> {
    text.trim().parse().map_err(|_| ServiceError::invalid(format!("{name}: {text:?} is not a valid number")))
}

pub async fn onboard_request(mut form: Multipart) -> Result<OnboardRequest, ServiceError> {
    let (mut object_id, mut format, mut units, mut replace) = (None, None, None, false);
    let mut options = OnboardOptions::default();
    let mut mesh: Option<(Option<String>, Vec<u8>)> = None;
    let mut resources = Vec::new();
    let mut parts = 0;
    while let Some(field) = form.next_field().await.map_err(part_error)? {
        parts += 1;
        if parts > MAX_MULTIPART_PARTS {
            return Err(ServiceError::invalid(format!("multipart body: more than {MAX_MULTIPART_PARTS} parts, over the limit")));
        }
        let name = field.name().unwrap_or_default().to_string();
        let file_name = field.file_name().map(str::to_string);
        match name.as_str() {
            "mesh" => mesh = Some((file_name, field.bytes().await.map_err(part_error)?.to_vec())),
            "resource" => {
                let Some(file_name) = file_name else {
                    return Err(ServiceError::invalid(format!("resource part {} has no file name (the name the mesh refers to it by)", resources.len())));
                };
                resources.push(ResourceInput { name: file_name, data: field.bytes().await.map_err(part_error)?.to_vec().into() });
            }
            "object_id" | "format" | "units" | "replace" | "level" | "in_plane" | "pca" | "descriptors" | "patch_rows" => {
                let text = field.text().await.map_err(part_error)?;
                match name.as_str() {
                    "object_id" => object_id = Some(text),
                    "format" => format = Some(text),
                    "units" => units = Some(text),
                    "replace" => replace = matches!(text.trim(), "true" | "1" | "yes"),
                    "level" => options.level = number(&name, &text)?,
                    "in_plane" => options.in_plane = number(&name, &text)?,
                    "pca" => options.pca = text.parse().map_err(|e| ServiceError::invalid(format!("pca: {e}")))?,
                    "descriptors" => options.descriptors = text.parse().map_err(|e: String| ServiceError::invalid(format!("descriptors: {e}")))?,
                    _ => options.patch_rows = text.parse().map_err(|e: String| ServiceError::invalid(format!("patch_rows: {e}")))?,
                }
            }
            other => {
                return Err(ServiceError::invalid(format!(
                    "unknown multipart part {other:?} (expected object_id, mesh, resource, format, units, replace, level, in_plane, pca, descriptors, patch_rows)"
                )))
            }
        }
    }
    let object_id = object_id.ok_or_else(|| ServiceError::invalid("multipart body: the object_id part is missing"))?;
    let (mesh_name, data) = mesh.ok_or_else(|| ServiceError::invalid("multipart body: the mesh file part is missing"))?;
    let from_extension = mesh_name.as_deref().and_then(|n| std::path::Path::new(n).extension()).and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let format = format.or(from_extension).ok_or_else(|| ServiceError::invalid("multipart body: give a format part, or a mesh file name with its extension"))?;
    Ok(OnboardRequest { object_id, mesh: MeshInput { data: data.into(), format, units, resources }, options, replace })
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::extract::FromRequest;

    async fn parse(body: String) -> Result<OnboardRequest, ServiceError> {
        let request = axum::http::Request::builder().header("content-type", "multipart/form-data; boundary=B").body(axum::body::Body::from(body)).unwrap();
        onboard_request(Multipart::from_request(request, &()).await.unwrap()).await
    }

    fn part(name: &str, file: &str, data: &str) -> String {
        format!("--B\r\nContent-Disposition: form-data; name=\"{name}\"; filename=\"{file}\"\r\n\r\n{data}\r\n")
    }

    #[tokio::test]
    async fn bodies_with_too_many_parts_are_refused() {
        let head = format!("{}{}", part("object_id", "", "box").replace("; filename=\"\"", ""), part("mesh", "m.obj", "v 0 0 0"));
        let body = |resources: usize| format!("{head}{}--B--\r\n", (0..resources).map(|i| part("resource", &format!("{i}.png"), "x")).collect::<String>());
        assert_eq!(parse(body(MAX_MULTIPART_PARTS - 2)).await.unwrap().mesh.resources.len(), MAX_MULTIPART_PARTS - 2);
        let e = parse(body(MAX_MULTIPART_PARTS - 1)).await.unwrap_err();
        assert_eq!(e.message, format!("multipart body: more than {MAX_MULTIPART_PARTS} parts, over the limit"));
    }
}
