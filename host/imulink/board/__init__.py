"""A board and the ways to reach it: the link (any pyserial URL), serial ports, the fault
proxy, emulated boards with their chip models, and flashing."""
