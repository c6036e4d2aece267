"""The PC link: frame codec (no I/O), emulated UART, real serial and CAN transports."""
