//! Whitted-style shading: direct light with shadow rays (hard for point lights,
//! soft for area lights), Phong highlights, recursive mirror reflection and
//! refraction, ambient term.
//!
//! OWNER: shading helper.
