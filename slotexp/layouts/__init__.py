"""The Foxglove layout shipped with slotexp (slot.json; built by slotexp.layout)."""
