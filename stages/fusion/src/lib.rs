//! The `fusion` stage: raw sensor samples (`RawImuFrame`) to oriented IMU frames (`ImuFrame`).
