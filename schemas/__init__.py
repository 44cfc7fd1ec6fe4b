"""The public contract: message Structs, key table and codec."""
