//! The railmon iceoryx2 bus: zero-copy payloads, service names, publisher and subscriber helpers.
