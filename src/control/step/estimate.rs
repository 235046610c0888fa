//! The estimator: both disturbance observers of the force balance on the piston, in one
//! place — the controlled stop's (the force the model does not explain, low-passed) and the
//! running step's (a momentum observer whose estimate the feed-forward cancels).

/// Both observers' state, N (toward +x).
#[derive(Clone, Debug)]
pub(super) struct Estimator {
    /// The stop's estimate of the force the model does not explain, N.
    pub stop_n: f32,
    /// The running observer's state, N: its bandwidth times the momentum the known forces
    /// and the estimate account for (NaN: restarts next cycle).
    pub load_state: f32,
    /// The running observer's estimate as cancelled, N.
    pub load_n: f32,
}

impl Estimator {
    pub(super) fn new() -> Self {
        Estimator {
            stop_n: 0.0,
            load_state: f32::NAN,
            load_n: 0.0,
        }
    }
}
