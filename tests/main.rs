//! Integration tests, one binary: each area in its own module folder.

mod core;
mod ecs;
mod export;
