//! What the fusion tests share: the assembler's settings with VQF's own defaults (the reference's),
//! 60 Hz output, 50 ms longest gap and 30 ms longest wait.
#![allow(dead_code)]

use imuflow_fusion::assembler::{Origin, Settings};
use imuflow_fusion::filter::VqfParams;
use imuflow_fusion::sensor::{MagnetometerUse, OrientationSource, SensorSettings};

pub fn settings(origin: Origin) -> Settings {
    Settings {
        sensor: SensorSettings {
            vqf: VqfParams::default(),
            orientation: OrientationSource::Auto,
            magnetometer: MagnetometerUse::Auto,
            sensor_rate_hz: None,
            max_gap_s: 0.05,
            output_rate_hz: 60.0,
            latency: imuflow_fusion::sensor::Latency::Smooth,
        },
        max_latency_s: 0.03,
        origin,
        sites: imuflow_body::SiteMask::of(imuflow_body::Imu::SIX),
    }
}
