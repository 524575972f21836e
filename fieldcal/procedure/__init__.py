"""The procedure: loading, the engine (a pure state machine), its events, stillness and averaging."""
