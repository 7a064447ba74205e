# Sourced by scripts/poweron.sh and scripts/poweron_norest.sh: the simulated units' lasting
# gyro errors, one consumer (MPU-9250) and one industrial (ADIS16448) unit.
lasting() { # grade → the lasting terms of one unit of it
  case "$1" in
    mpu-9250) echo "{term: gyro_scale, scale: [0.021, -0.027, 0.014]}|{term: gyro_misalignment, matrix: [[0, 0.012, -0.008], [-0.015, 0, 0.010], [0.006, -0.011, 0]]}|{term: gyro_g_sensitivity, matrix: [[1.5e-4, 0, 0], [0, -1.2e-4, 0], [0, 0, 0.8e-4]]}" ;;
    adis16448) echo "{term: gyro_scale, scale: [0.002, -0.003, 0.001]}|{term: gyro_misalignment, matrix: [[0, 0.0009, -0.0006], [-0.0011, 0, 0.0008], [0.0005, -0.0009, 0]]}|{term: gyro_g_sensitivity, matrix: [[1.0e-5, 0, 0], [0, -1.2e-5, 0], [0, 0, 0.8e-5]]}" ;;
  esac
}
