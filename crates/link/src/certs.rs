//! The certificates of a run across hosts over mutual TLS, made with
//! `rcgen`: a CA of the run's own and one certificate per host, each in a
//! directory of its own (`ca.pem`, `cert.pem`, `key.pem`), the layout
//! [`crate::LinkOptions::tls`] reads. The CA's key stays in the output
//! directory and goes nowhere else.

use std::path::{Path, PathBuf};

use rcgen::{
    BasicConstraints, CertificateParams, CertifiedIssuer, DnType, ExtendedKeyUsagePurpose, IsCa,
    KeyPair, KeyUsagePurpose,
};

use crate::error::{LinkError, Result};

/// The common name of a host's certificate (access-control rules name it).
pub fn common_name(host: &str) -> String {
    format!("rotorhive-{host}")
}

fn err(what: &str) -> impl FnOnce(rcgen::Error) -> LinkError + '_ {
    move |e| LinkError::Tls(format!("{what}: {e}"))
}

/// Writes a CA (`ca.pem`, `ca.key`) and the directories `head/` (valid for
/// `head_names`, loopback names always included) and `worker-1/` ..
/// `worker-N/` under `out`; returns the host directories.
pub fn make(out: &Path, workers: usize, head_names: &[String]) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out)
        .map_err(|e| LinkError::Tls(format!("cannot create {}: {e}", out.display())))?;
    let mut ca = CertificateParams::default();
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.distinguished_name.push(DnType::CommonName, "rotorhive run CA");
    ca.key_usages = vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ];
    let ca_key = KeyPair::generate().map_err(err("a key for the CA"))?;
    let ca_key_pem = ca_key.serialize_pem();
    let ca = CertifiedIssuer::self_signed(ca, ca_key).map_err(err("the CA"))?;
    write(&out.join("ca.pem"), &ca.pem(), false)?;
    write(&out.join("ca.key"), &ca_key_pem, true)?;
    let mut names = vec!["localhost".to_string(), "127.0.0.1".into(), "::1".into()];
    for n in head_names {
        if !names.contains(n) {
            names.push(n.clone());
        }
    }
    let mut hosts = vec![("head".to_string(), names)];
    hosts.extend((1..=workers).map(|i| (format!("worker-{i}"), vec![format!("worker-{i}")])));
    let mut dirs = Vec::new();
    for (host, names) in &hosts {
        let mut p = CertificateParams::new(names.clone())
            .map_err(|e| LinkError::Tls(format!("names of {host} {names:?}: {e}")))?;
        p.distinguished_name.push(DnType::CommonName, common_name(host));
        p.key_usages = vec![KeyUsagePurpose::DigitalSignature, KeyUsagePurpose::KeyEncipherment];
        p.extended_key_usages =
            vec![ExtendedKeyUsagePurpose::ServerAuth, ExtendedKeyUsagePurpose::ClientAuth];
        let key = KeyPair::generate().map_err(err("a host key"))?;
        let cert = p.signed_by(&key, &ca).map_err(err("a host certificate"))?;
        let dir = out.join(host);
        std::fs::create_dir_all(&dir)
            .map_err(|e| LinkError::Tls(format!("cannot create {}: {e}", dir.display())))?;
        write(&dir.join("ca.pem"), &ca.pem(), false)?;
        write(&dir.join("cert.pem"), &cert.pem(), false)?;
        write(&dir.join("key.pem"), &key.serialize_pem(), true)?;
        if let Some(slot) = host.strip_prefix("worker-") {
            // The slot this certificate may join as (the head's access
            // control holds it to that).
            write(&dir.join("slot"), &format!("{slot}\n"), false)?;
        }
        dirs.push(dir);
    }
    Ok(dirs)
}

/// The slot a worker's certificate directory holds: its `slot` file, else
/// a directory named `worker-N` (made by `hive certs` before the file).
pub fn slot_of(dir: &Path) -> Option<u32> {
    match std::fs::read_to_string(dir.join("slot")) {
        Ok(s) => s.trim().parse().ok(),
        Err(_) => dir.file_name()?.to_str()?.strip_prefix("worker-")?.parse().ok(),
    }
}

/// Writes `text`; a key readable by its owner only.
fn write(path: &Path, text: &str, secret: bool) -> Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(if secret { 0o600 } else { 0o644 })
        .open(path)
        .and_then(|mut f| f.write_all(text.as_bytes()))
        .map_err(|e| LinkError::Tls(format!("cannot write {}: {e}", path.display())))
}
