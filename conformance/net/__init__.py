"""Everything that opens a socket: client, emulator server, recording proxy."""
