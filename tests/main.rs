//! Integration tests, one binary: each area in its own module folder.

mod anatomy;
mod common;
mod core;
mod ecs;
mod export;
mod gltf;
mod scene;
