"""What crosses a process boundary: the Zenoh session, key expressions and the typed,
versioned messages."""
