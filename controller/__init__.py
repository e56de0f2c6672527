"""Controller core: linear tooling, the state-shared model, adaptation, switching,
MPC / H-infinity / MRAC and reference trajectories. Pure: no I/O, knows no plant."""
