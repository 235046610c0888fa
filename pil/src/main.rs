//! `fpc-pil`: see the library's documentation.

use std::path::PathBuf;

use fpc_pil::board::Board;
use fpc_pil::chip::{Chip, ChipOptions};
use fpc_pil::elf::Image;

fn main() {
    let elf = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| "target/thumbv7em-none-eabihf/release/fpc".into());
    let image = Image::read(&elf).unwrap();
    let world = hal_sim::run::world(
        &hal_sim::plant::model::MachineModel::reference(),
        1,
        0,
        0.005,
    );
    let mut log = fpc_pil::log::DefmtLog::new(&image.bytes).unwrap();
    let rtt_base = image.symbol("_SEGGER_RTT").unwrap();
    let mut chip = Chip::new(image, Board::new(world), ChipOptions::default()).unwrap();
    chip.boot().unwrap();
    let t0 = std::time::Instant::now();
    let mut rtt = None;
    for k in 0..20000 {
        if let Err(e) = chip.run_period() {
            eprintln!("error at period {k}: {e} pc {:#x}", chip.pc());
            break;
        }
        if rtt.is_none() {
            rtt = fpc_pil::rtt::Rtt::attach(&chip, rtt_base).unwrap();
        }
        if let Some(r) = rtt {
            let mut b = Vec::new();
            r.read_up(&mut chip, 0, &mut b).unwrap();
            let t = chip.time_s();
            log.push(t, &b);
        }
    }
    {
        let soc = chip.soc();
        println!(
            "pending {:?}",
            (0..118)
                .filter(|&n| soc.nvic.pending[n])
                .collect::<Vec<_>>()
        );
        println!(
            "enabled {:?}",
            (0..118)
                .filter(|&n| soc.nvic.enabled[n])
                .collect::<Vec<_>>()
        );
        println!(
            "active {:?}",
            (0..118).filter(|&n| soc.nvic.active[n]).collect::<Vec<_>>()
        );
        println!(
            "prio {:?}",
            (16..118)
                .filter(|&n| soc.nvic.priority[n] != 0)
                .map(|n| (n - 16, soc.nvic.priority[n]))
                .collect::<Vec<_>>()
        );
        println!("sleeping {} event {}", soc.sleeping, soc.event);
    }
    for (t, l) in &log.lines {
        println!("{t:.6} {l}");
    }
    let soc = chip.soc();
    println!(
        "t {:.4} s, {} instructions, pc {:#x}, ipsr {}, resets {:?}, wall {:?}",
        fpc_pil::time::seconds(soc.time),
        soc.instructions,
        0,
        soc.ipsr,
        soc.resets,
        t0.elapsed()
    );
}
