"""FastAPI node: the v1 REST contract of ssmpc (talks to controllers over Zenoh)."""
