//! Hardware abstraction: narrow traits only. `hal-sim` implements them on the host, `board/` on the target.
