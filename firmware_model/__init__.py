"""The STM32F103 firmware model: 500 Hz three-loop servo, safety, command handling."""
