//! The drive: ties control, modes, supervision and the dictionary together; `fast_tick` and `slow_tick`.
