"""The icoBoard's FPGA design (gateware), in Amaranth HDL: protocol v2 on an iCE40-HX8K.

One small component per block, each with its own simulation test (tests/test_gateware_*.py):

    spi.SpiPeripheral          the Pi's SPI (mode 0), oversampled at 100 MHz
    protocol.ProtocolEngine    protocol v2 exactly as icefloe.wire.icoboard defines it
    quadrature.QuadratureDecoder, pwm.PwmOutput, watchdog.Watchdog
    core.IcoBoardCore          all of them, built from the peripheral list (wire.icoboard.Peripherals)
    platform.IcoBoardPlatform  the board, and its pin map; top.IcoBoardTop: the core on those pins
    build.build                the bitstream (`icefloe gateware build`)
    cxxsim.CompiledBoard       the design compiled (CXXRTL + g++): the simulator's "gateware" board

docs/gateware.md explains the design, the wiring and the measured figures.
"""
