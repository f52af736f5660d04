//! What the physics tests share: simulated frames as EPRY's shots, and one offline EPRY
//! run over the whole field.

use fpm_physics::reconstruct::{run, Field, Outcome, Settings, Shot};
use fpm_physics::simulate::SimFrame;
use fpm_physics::{Image, LedGeometry, System};

/// Each simulated frame with its image (in the frames' order).
pub fn shots<'a>(frames: &'a [SimFrame], images: &'a [Image]) -> Vec<Shot<'a>> {
    frames
        .iter()
        .zip(images)
        .map(|(f, image)| Shot {
            led: f.led,
            also: &f.also,
            image,
        })
        .collect()
}

/// Offline EPRY over the whole field, `passes` passes.
pub fn epry(
    system: &System,
    geometry: &LedGeometry,
    shots: &[Shot<'_>],
    settings: Settings,
    passes: usize,
) -> Outcome {
    run(
        system,
        geometry,
        Field::default(),
        shots,
        settings,
        passes,
        |_, _| {},
    )
    .expect("a bright-field frame")
}
