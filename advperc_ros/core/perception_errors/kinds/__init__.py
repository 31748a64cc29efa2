"""One module per error kind, each defining its `ErrorKind` record (`KIND`); the registry orders them."""
