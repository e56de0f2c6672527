"""Long closed-loop runs over the real services with faults injected (``ssmpc soak``)."""
