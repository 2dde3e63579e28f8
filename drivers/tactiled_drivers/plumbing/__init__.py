"""What the drivers share and no URL scheme names: ``port_reader`` and ``read_thread`` (a serial
port read as its bytes arrive, guarded by one thread), ``framing`` (the vendor framers'
counters, sequence and clock), ``futures`` (the drivers' asyncio wake-up)."""
