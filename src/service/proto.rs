//! The gRPC API generated from `proto/b2tfpose/v1/pose_service.proto` (messages, the
//! `PoseService` server trait and its client), and the encoded descriptor set that server
//! reflection serves.

#![allow(clippy::all, missing_docs)]

tonic::include_proto!("b2tfpose.v1");

/// `FileDescriptorSet` of the API, for `grpc.reflection`.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/b2tfpose_descriptor.bin"));
