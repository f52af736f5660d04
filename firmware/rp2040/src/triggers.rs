//! Camera trigger lines: a GPIO output driven by the controller logic, and a GPIO
//! input whose edges are time-stamped the moment they are seen.

use embassy_rp::gpio::{Input, Output};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::Instant;
use fpm_firmware::TriggerOut;
use fpm_protocol::Edge;

/// Edges from the camera, with their device time in µs.
pub type Edges = Channel<CriticalSectionRawMutex, (Edge, u64), 32>;

/// The trigger output line.
pub struct TriggerPin(pub Output<'static>);

impl TriggerOut for TriggerPin {
    fn set_level(&mut self, high: bool) {
        if high {
            self.0.set_high();
        } else {
            self.0.set_low();
        }
    }
}

/// Watch the trigger input and queue every edge.
#[embassy_executor::task]
pub async fn trigger_in_task(mut pin: Input<'static>, edges: &'static Edges) -> ! {
    loop {
        // Wait for the edge away from the current level, so even a short pulse is seen
        // as the pair of edges it is.
        let edge = if pin.is_high() {
            pin.wait_for_falling_edge().await;
            Edge::Falling
        } else {
            pin.wait_for_rising_edge().await;
            Edge::Rising
        };
        let at = Instant::now().as_micros();
        if edges.try_send((edge, at)).is_err() {
            defmt::warn!("trigger-in edges arrive faster than they are handled; one dropped");
        }
    }
}
