//! Who may connect: the `[server] token_file` token, compared in constant time, and the refusal
//! to listen beyond this host without one.
//!
//! [`Access::prepare`] runs at start-up, before the arm is brought up: it reads the token (the
//! file's first line, trimmed) and refuses a listener on an address other hosts can reach when
//! there is no token, so a daemon that would be open to the network never starts.

use std::fmt;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use crate::config::Server;
use crate::textfile::{read_text, MAX_TEXT_BYTES};

/// Why the daemon refuses to serve.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AccessError {
    /// The token file could not be read (missing, unreadable, not UTF-8).
    #[error("{}: cannot read the token file ([server] token_file): {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why: what the operating system said, or not a regular file, or too large.
        source: crate::textfile::TextFileError,
    },
    /// The token file holds nothing but blanks.
    #[error(
        "{}: the token file ([server] token_file) is empty: its first line is the token",
        path.display()
    )]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The token file's first line is blank, a later one not: only the first line is read.
    #[error(
        "{}: the first line of the token file ([server] token_file) is blank: the token is the \
         first line, and line {line} is not read (move the token to line 1)",
        path.display()
    )]
    BlankFirstLine {
        /// The file.
        path: PathBuf,
        /// The first line that is not blank, from 1.
        line: usize,
    },
    /// A listener other hosts can reach, and no token.
    #[error(
        "refusing to listen on {addr} without [server] token_file: any host that reaches it \
         could move the arm; set token_file, or listen on a loopback address such as \
         127.0.0.1:7878"
    )]
    Exposed {
        /// The address listened on.
        addr: SocketAddr,
    },
}

/// The token a client's first line must carry. Its `Debug` does not show it, and comparing two
/// takes the same time wherever they differ.
#[derive(Clone)]
pub struct Token(Box<[u8]>);

impl PartialEq for Token {
    fn eq(&self, other: &Token) -> bool {
        self.matches(&other.0)
    }
}

impl Eq for Token {}

impl Token {
    /// A token of these bytes; `None` when empty (an empty token would admit anyone).
    pub fn new(token: impl Into<Vec<u8>>) -> Option<Token> {
        let token = token.into();
        (!token.is_empty()).then(|| Token(token.into_boxed_slice()))
    }

    /// The token in `path`: its first line, leading and trailing whitespace trimmed.
    pub fn read(path: &Path) -> Result<Token, AccessError> {
        let text = read_text(path, MAX_TEXT_BYTES).map_err(|source| AccessError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let first = text.lines().next().unwrap_or("").trim();
        Token::new(first).ok_or_else(|| {
            let path = path.to_path_buf();
            match crate::textfile::first_text_line(&text) {
                Some(line) => AccessError::BlankFirstLine { path, line },
                None => AccessError::Empty { path },
            }
        })
    }

    /// Whether `given` is this token, in a time that depends on `given`'s length only.
    pub fn matches(&self, given: &[u8]) -> bool {
        constant_time_eq(&self.0, given)
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(..)")
    }
}

/// Whether `secret == given`, without an early exit: every byte of `given` is compared (against
/// `secret` repeated), so the time taken tells an attacker `given`'s length, which they chose,
/// and nothing about where the two differ or how long `secret` is.
pub fn constant_time_eq(secret: &[u8], given: &[u8]) -> bool {
    // Lengths differ: the comparison runs all the same, and the result is false.
    let mut diff = u8::from(secret.len() != given.len());
    if !secret.is_empty() {
        for (i, &b) in given.iter().enumerate() {
            diff |= secret[i % secret.len()] ^ b;
        }
    }
    // Keep the optimizer from turning the loop into an early exit.
    std::hint::black_box(diff) == 0 && !secret.is_empty()
}

/// Whether only this host can reach `addr`: a loopback address (IPv4 127/8, `::1`, or an
/// IPv4-mapped loopback).
pub fn is_local(addr: SocketAddr) -> bool {
    addr.ip().to_canonical().is_loopback()
}

/// The server's access settings, checked.
#[derive(Debug, Clone, Default)]
pub struct Access {
    /// The token clients must send first; `None`: no `auth` needed.
    pub token: Option<Token>,
}

impl Access {
    /// Reads the token of `server` (when set) and checks that a listener on `addr` may serve
    /// with it.
    ///
    /// # Errors
    /// [`AccessError::Read`], [`AccessError::Empty`] or [`AccessError::BlankFirstLine`] for a
    /// token file that cannot be used;
    /// [`AccessError::Exposed`] for a non-loopback `addr` without a token.
    pub fn prepare(server: &Server, addr: SocketAddr) -> Result<Access, AccessError> {
        let token = server.token_file.as_deref().map(Token::read).transpose()?;
        Access::check(token, addr)
    }

    /// Checks that a listener on `addr` may serve with `token`.
    ///
    /// # Errors
    /// [`AccessError::Exposed`] for a non-loopback `addr` without a token.
    pub fn check(token: Option<Token>, addr: SocketAddr) -> Result<Access, AccessError> {
        if token.is_none() && !is_local(addr) {
            return Err(AccessError::Exposed { addr });
        }
        Ok(Access { token })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn equal_bytes_only_match() {
        assert!(constant_time_eq(b"s3cret", b"s3cret"));
        for given in [
            &b""[..],
            b"s3cre",
            b"s3cret ",
            b"s3creT",
            b"S3cret",
            b"s3crets3cret",
            b"xxxxxx",
        ] {
            assert!(!constant_time_eq(b"s3cret", given), "{given:?}");
        }
        assert!(!constant_time_eq(b"", b""), "an empty secret admits no one");
        assert!(!constant_time_eq(b"", b"a"));
        // A given that repeats the secret is still not it.
        assert!(!constant_time_eq(b"ab", b"abab"));
    }

    #[test]
    fn the_token_is_the_first_line_trimmed() {
        let dir = std::env::temp_dir().join(format!("snakectl-token-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("token");
        std::fs::write(&file, "  hunter2 \t\nsecond line\n").unwrap();
        let token = Token::read(&file).unwrap();
        assert!(token.matches(b"hunter2"));
        assert!(!token.matches(b"  hunter2"));
        assert!(!token.matches(b"second line"));
        assert_eq!(format!("{token:?}"), "Token(..)", "Debug hides the token");

        for empty in ["", "\n", " \t\n  \n"] {
            std::fs::write(&file, empty).unwrap();
            let e = Token::read(&file).unwrap_err();
            assert!(matches!(e, AccessError::Empty { .. }), "{empty:?}: {e}");
            assert!(e.to_string().contains(&*file.to_string_lossy()), "{e}");
        }
        // A token below a blank first line is not read, and not called empty either.
        std::fs::write(&file, "   \n\nnext\n").unwrap();
        let e = Token::read(&file).unwrap_err();
        assert!(
            matches!(e, AccessError::BlankFirstLine { line: 3, .. }),
            "{e}"
        );
        let shown = e.to_string();
        assert!(
            shown.contains("first line of the token file ([server] token_file) is blank")
                && shown.contains("line 3 is not read")
                && !shown.contains("empty"),
            "{shown}"
        );
        let missing = dir.join("absent");
        let e = Token::read(&missing).unwrap_err();
        assert!(matches!(e, AccessError::Read { .. }), "{e}");
        assert!(e.to_string().contains("absent"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn beyond_loopback_a_token_is_required() {
        let token = || Token::new("t");
        for local in [
            "127.0.0.1:7878",
            "127.1.2.3:1",
            "[::1]:7878",
            "[::ffff:127.0.0.1]:9",
        ] {
            let addr: SocketAddr = local.parse().unwrap();
            assert!(is_local(addr), "{addr}");
            assert!(Access::check(None, addr).is_ok(), "{addr}");
        }
        for exposed in [
            "0.0.0.0:7878",
            "192.168.1.5:7878",
            "[::]:7878",
            "[fe80::1]:1",
        ] {
            let addr: SocketAddr = exposed.parse().unwrap();
            let e = Access::check(None, addr).unwrap_err();
            let message = e.to_string();
            assert!(message.contains(exposed), "{message}");
            assert!(message.contains("token_file"), "{message}");
            assert!(message.contains("loopback"), "{message}");
            assert!(Access::check(token(), addr).unwrap().token.is_some());
        }
    }
}
