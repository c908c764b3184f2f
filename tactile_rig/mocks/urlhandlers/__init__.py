"""pyserial URL handlers: ``rigsim://`` (in-process mocks) and ``rigfault://`` (fault injection).

pyserial finds ``protocol_<scheme>`` modules in the packages of ``serial.protocol_handler_packages``;
:mod:`tactile_rig.drivers.transport` appends this package on import.
"""
