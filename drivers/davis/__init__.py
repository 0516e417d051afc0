"""DAVIS cameras over USB (pyusb): driver, stream decoder and a device emulator (issue 6)."""
