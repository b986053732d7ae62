//! flowgate-sim: the simulated rig.
//!
//! It depends on `flowgate-protocol` only: like real firmware, it knows nothing of the
//! gateway and speaks only the wire protocols.
