//! Pure control math in fixed point: frames, angles, transforms, controllers, modulation.
