"""Simulator: exact truth and sensor data for tests and benchmarks.

motion (profiles) -> strapdown (exact IMU + truth) -> imu_errors / gnss / baro (sensors)
-> scenarios (SCENARIOS registry, SimRun) -> writer (write_sim_dir).
"""
