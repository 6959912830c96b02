"""CiA 402 drive over CANopen, the master side (plain Python: no rclpy in this layer)."""

from __future__ import annotations

from ladrc_contract.lazy_api import lazy_api

# the public API (name: module), imported on first use: importing the package
# loads nothing else
_EXPORTS = {
    'AnalogScale': 'units',
    'CW_FAULT_RESET': 'ds402',
    'Command': 'ds402',
    'DeviceFile': 'device_file',
    'DriveUnits': 'units',
    'ERROR_REGISTER': 'emcy',
    'MODE_CYCLIC_SYNC_VELOCITY': 'ds402',
    'MODE_PROFILE_VELOCITY': 'ds402',
    'PlanError': 'device_file',
    'QUICK_STOP_OPTION_CODE': 'ds402',
    'REG_COMMUNICATION': 'emcy',
    'REG_GENERIC': 'emcy',
    'SW_REMOTE': 'ds402',
    'SW_VOLTAGE_ENABLED': 'ds402',
    'State': 'ds402',
    'command_of': 'ds402',
    'entry_range': 'device_file',
    'load_device': 'device_file',
    'make_plan': 'device_file',
    'plan_text': 'device_file',
    'statusword_bits': 'ds402',
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_api(__name__, _EXPORTS)
