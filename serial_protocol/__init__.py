"""The PC link: frame codec (no I/O), emulated UART, real serial and CAN transports.

==================  ==========================================================  ==========
module              what                                                        imports
==================  ==========================================================  ==========
``messages``        one frozen dataclass per message; enums                     nothing
``frame``           ``encode(msg, seq)``, ``Decoder.feed(data)``, CRCs          messages
``uart``            ``EmulatedUart`` (one direction, paced), decimation         nothing
``exceptions``      the project's exception tree                                nothing
``transport``       ``SerialLink`` over pyserial ``serial_for_url``             pyserial
``can_link``        the messages over classic CAN, ``CanLink`` (python-can)     python-can
``host``            ``BoardClient``: command, ACK timeout, retries, telemetry   a Link
``telemetry_csv``   telemetry rows to CSV                                       csv
==================  ==========================================================  ==========

The wire format is specified in ``docs/protocol.md``.
"""
