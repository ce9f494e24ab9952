"""bodebench bus drivers: CAN (python-can) and serial (pyserial)."""
