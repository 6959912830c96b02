"""The emulated CiA 402 drive (simulator side): device state machine, CANopen node, test bus."""
