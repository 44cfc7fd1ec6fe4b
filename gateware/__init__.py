"""The icoBoard gateware."""
