//! Built-in triangle primitives (quad, box, UV sphere, cylinder) as indexed meshes.
//!
//! OWNER: scene helper.
