//! One control cycle of the run log as the loop records it, and its values in the log's
//! columns.

use fpc::status::Status;
use fpc::units::Section;

use crate::board::world::World;
use crate::runlog::RunLog;

/// One control cycle of the run log: 80 bytes instead of 18 separate `f64` (144).
#[derive(Clone, Copy, Debug)]
pub struct CapturedRow {
    /// x, x_slave, θ, F_master, F_slave, p_A, p_B, x_ref, θ_ref, v as in [`COLUMNS`](super::super::COLUMNS).
    status: [f32; 10],
    cycle: u32,
    fault: u8,
    /// p_A, p_B, V_A, V_B (plant truth) as in [`COLUMNS`](super::super::COLUMNS).
    truth: [f64; 4],
}

impl CapturedRow {
    /// The row of `status` and the plant's chambers in `w`, now; each section's force as its
    /// reading reports it (`[sensors.force]`).
    #[inline]
    pub fn new(status: &Status, w: &World) -> Self {
        let c = &w.plant.chambers;
        let force = &w.sensors.force;
        let reported = |section: Section, f: f32| -> f32 {
            if force.exact() {
                f
            } else {
                force.reading_n(section, f64::from(f)) as f32
            }
        };
        CapturedRow {
            status: [
                status.position_m,
                status.slave_position_m,
                status.theta_rad,
                reported(Section::Master, status.force_master_n),
                reported(Section::Slave, status.force_slave_n),
                status.pressure_a_pa,
                status.pressure_b_pa,
                status.reference_m,
                status.theta_reference_rad,
                status.velocity_mps,
            ],
            cycle: u32::try_from(w.cycle()).unwrap_or(u32::MAX),
            fault: status.faults.first().map_or(0, |f| f as u8),
            truth: [
                c.a.pressure_pa,
                c.b.pressure_pa,
                c.a.volume_m3,
                c.b.volume_m3,
            ],
        }
    }

    /// A row of control cycle `k` whose values all differ from row to row.
    #[cfg(test)]
    pub fn synthetic(k: u32) -> Self {
        let x = k as f32;
        CapturedRow {
            status: std::array::from_fn(|i| x * 1e-4 + i as f32),
            cycle: k,
            fault: (k % 3) as u8,
            truth: std::array::from_fn(|i| f64::from(k) * 0.5 + i as f64),
        }
    }

    /// The control cycle of the row.
    pub fn cycle(&self) -> u64 {
        u64::from(self.cycle)
    }

    /// The row's values in [`COLUMNS`](super::super::COLUMNS)' order, with the line pressures in force.
    pub fn values(&self, suction_pa: f64, discharge_pa: f64) -> [f64; 18] {
        let [a, b, c, d, e, f, g, h, i, j] = self.status.map(f64::from);
        let [pa, pb, va, vb] = self.truth;
        [
            World::time_s_at(u64::from(self.cycle)),
            a,
            b,
            c,
            d,
            e,
            f,
            g,
            h,
            i,
            j,
            f64::from(self.fault),
            pa,
            pb,
            va,
            vb,
            suction_pa,
            discharge_pa,
        ]
    }
}

/// Appends the captured `rows` to `log` (which has [`COLUMNS`](super::super::COLUMNS)), one column at a time; `lines`
/// are the line-pressure changes (first row index, suction, discharge).
pub fn fill_columns(rows: &[CapturedRow], lines: &[(usize, f64, f64)], log: &mut RunLog) {
    let n = rows.len();
    for (j, column) in log.columns.iter_mut().enumerate() {
        column.reserve_exact(n);
        match j {
            0 => column.extend(rows.iter().map(|r| World::time_s_at(u64::from(r.cycle)))),
            1..=10 => column.extend(
                rows.iter()
                    .map(|r| r.status.get(j - 1).copied().map_or(f64::NAN, f64::from)),
            ),
            11 => column.extend(rows.iter().map(|r| f64::from(r.fault))),
            12..=15 => column.extend(
                rows.iter()
                    .map(|r| r.truth.get(j - 12).copied().unwrap_or(f64::NAN)),
            ),
            _ => {
                // Each line pressure holds from its change to the next.
                let ends = lines.iter().skip(1).map(|l| l.0).chain([n]);
                for (&(start, suction, discharge), end) in lines.iter().zip(ends) {
                    let v = if j == 16 { suction } else { discharge };
                    column.extend(std::iter::repeat_n(v, end.saturating_sub(start)));
                }
            }
        }
    }
}
