//! The serial line to the PSD controller.

use std::path::Path;
use tokio_serial::SerialPortBuilderExt;

#[derive(Debug, thiserror::Error)]
pub enum SerialError {
    #[error("serial port {path} does not exist (is the device plugged in? is the path right?)")]
    Missing { path: String },
    #[error("serial port {path} is in use by another program (flowgate opens it exclusively)")]
    Busy { path: String },
    #[error("cannot open serial port {path}: {source}")]
    Open { path: String, source: tokio_serial::Error },
}

/// Open `path` at `baud`, exclusively: a second gateway on the same port is refused.
pub fn open_serial(path: &Path, baud: u32) -> Result<tokio_serial::SerialStream, SerialError> {
    let name = path.to_string_lossy().into_owned();
    if !path.exists() {
        return Err(SerialError::Missing { path: name });
    }
    tokio_serial::new(&name, baud).open_native_async().map_err(|source| {
        // serialport sets TIOCEXCL and takes an flock on the tty. Another process holding it
        // reads as EBUSY at open (for a user without CAP_SYS_ADMIN, which TIOCEXCL does not
        // bind), or as a held lock ("NoDevice") for root.
        let busy = source.description.to_ascii_lowercase().contains("busy");
        let locked = source.kind == tokio_serial::ErrorKind::NoDevice && source.description.contains("lock");
        if busy || locked {
            SerialError::Busy { path: name }
        } else {
            SerialError::Open { path: name, source }
        }
    })
}
