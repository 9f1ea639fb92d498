//! The thermal nodes: the winding and the housing, heated by the copper loss, and the power stage, heated by the
//! conduction losses of the switches; one Euler step per period (their time constants are 20 s and more).

use super::Plant;

impl Plant {
    /// Advance the three temperatures by `dt` with the mean losses of that time, in W.
    pub(super) fn update_thermal(&mut self, copper_loss_w: f64, switch_loss_w: f64, dt: f64) {
        let p = &self.params;
        let r_wh = p.winding_to_housing_k_per_w;
        let r_ha = p.housing_to_ambient_k_per_w;
        let c_w = p.winding_time_constant_s / r_wh;
        let c_h = p.housing_time_constant_s / r_ha;
        let flow_wh = (self.t_winding - self.t_housing) / r_wh;
        let flow_ha = (self.t_housing - p.ambient_c) / r_ha;
        self.t_winding += dt * (copper_loss_w - flow_wh) / c_w;
        self.t_housing += dt * (flow_wh - flow_ha) / c_h;
        let r_ps = p.power_stage_to_ambient_k_per_w;
        let c_ps = p.power_stage_time_constant_s / r_ps;
        self.t_power_stage += dt * (switch_loss_w - (self.t_power_stage - p.ambient_c) / r_ps) / c_ps;
    }
}
