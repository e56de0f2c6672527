"""The service's processes: plant node, controller node, their runners, and the
supervision of ``ssmpc up``."""
