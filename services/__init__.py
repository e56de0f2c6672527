"""The shell: Zenoh nodes, the timed loop, telemetry, persistence, studies and the CLI."""
