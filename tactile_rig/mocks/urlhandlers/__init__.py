"""pyserial URL handlers: ``rigsim://`` (in-process mocks) and ``rigfault://`` (fault injection).

pyserial finds ``protocol_<scheme>`` modules in the packages of ``serial.protocol_handler_packages``;
:mod:`tactile_rig` (the package root) appends this package on import, by name: a driver opening
``rigsim://...`` never imports a mock itself; pyserial loads the handler when such a URL is opened.
"""
