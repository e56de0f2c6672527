"""OPC UA link between a plant (served as a DCS serves it) and its controller.

:mod:`.settings` (endpoint, watchdog, heartbeat), :mod:`.certs` (CA and
certificates), :mod:`.namespace` (the ``urn:ssmpc`` address space), :mod:`.server`
(the plant side), :mod:`.client` (the controller side). See ``docs/opcua.md``.
"""
