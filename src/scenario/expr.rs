//! A small arithmetic expression language for parametric curves: numbers, the parameter `t`,
//! the constants `pi` and `e`, `+ - * / ^` (`^` binds tightest and associates to the right,
//! unary minus below it), parentheses and the functions `sin cos tan exp ln sqrt abs sinh cosh
//! tanh`. Nothing else: an expression cannot name a file, loop or call out. An expression is at
//! most [`MAX_LEN`] bytes long and nests parentheses, calls, signs and exponents at most
//! [`MAX_DEPTH`] deep, so that parsing, evaluating and dropping it never runs off the stack.

/// The longest expression accepted, bytes.
pub const MAX_LEN: usize = 4096;

/// The deepest nesting accepted: parentheses, function calls, signs and exponents, each level.
pub const MAX_DEPTH: usize = 64;

/// A parse error: the byte offset in the expression and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("at character {position}: {message}")]
pub struct ExprError {
    /// 0-based byte offset.
    pub position: usize,
    /// What is wrong.
    pub message: String,
}

/// A parsed expression in `t`.
#[derive(Debug, Clone, PartialEq)]
pub struct Expr(Node);

#[derive(Debug, Clone, PartialEq)]
enum Node {
    Num(f64),
    T,
    Neg(Box<Node>),
    Bin(char, Box<Node>, Box<Node>),
    Call(Func, Box<Node>),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Func {
    Sin,
    Cos,
    Tan,
    Exp,
    Ln,
    Sqrt,
    Abs,
    Sinh,
    Cosh,
    Tanh,
}

impl Func {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "sin" => Func::Sin,
            "cos" => Func::Cos,
            "tan" => Func::Tan,
            "exp" => Func::Exp,
            "ln" => Func::Ln,
            "sqrt" => Func::Sqrt,
            "abs" => Func::Abs,
            "sinh" => Func::Sinh,
            "cosh" => Func::Cosh,
            "tanh" => Func::Tanh,
            _ => return None,
        })
    }

    fn apply(self, x: f64) -> f64 {
        match self {
            Func::Sin => x.sin(),
            Func::Cos => x.cos(),
            Func::Tan => x.tan(),
            Func::Exp => x.exp(),
            Func::Ln => x.ln(),
            Func::Sqrt => x.sqrt(),
            Func::Abs => x.abs(),
            Func::Sinh => x.sinh(),
            Func::Cosh => x.cosh(),
            Func::Tanh => x.tanh(),
        }
    }
}

struct Parser<'a> {
    text: &'a [u8],
    pos: usize,
    /// Nesting of the operand being parsed (every nested operand passes through `unary`).
    depth: usize,
}

impl Parser<'_> {
    fn error<T>(&self, message: impl Into<String>) -> Result<T, ExprError> {
        Err(ExprError {
            position: self.pos,
            message: message.into(),
        })
    }

    fn skip_space(&mut self) {
        while self.pos < self.text.len() && self.text[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
    }

    fn peek(&mut self) -> Option<u8> {
        self.skip_space();
        self.text.get(self.pos).copied()
    }

    fn sum(&mut self) -> Result<Node, ExprError> {
        let mut left = self.product()?;
        while let Some(c @ (b'+' | b'-')) = self.peek() {
            self.pos += 1;
            let right = self.product()?;
            left = Node::Bin(c as char, Box::new(left), Box::new(right));
        }
        Ok(left)
    }

    fn product(&mut self) -> Result<Node, ExprError> {
        let mut left = self.unary()?;
        while let Some(c @ (b'*' | b'/')) = self.peek() {
            self.pos += 1;
            let right = self.unary()?;
            left = Node::Bin(c as char, Box::new(left), Box::new(right));
        }
        Ok(left)
    }

    fn unary(&mut self) -> Result<Node, ExprError> {
        if self.depth >= MAX_DEPTH {
            return self.error(format!("nested more than {MAX_DEPTH} deep"));
        }
        self.depth += 1;
        let node = self.signed();
        self.depth -= 1;
        node
    }

    fn signed(&mut self) -> Result<Node, ExprError> {
        match self.peek() {
            Some(b'-') => {
                self.pos += 1;
                Ok(Node::Neg(Box::new(self.unary()?)))
            }
            Some(b'+') => {
                self.pos += 1;
                self.unary()
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Node, ExprError> {
        let base = self.atom()?;
        if self.peek() == Some(b'^') {
            self.pos += 1;
            let exponent = self.unary()?;
            return Ok(Node::Bin('^', Box::new(base), Box::new(exponent)));
        }
        Ok(base)
    }

    fn atom(&mut self) -> Result<Node, ExprError> {
        match self.peek() {
            Some(b'(') => {
                self.pos += 1;
                let inner = self.sum()?;
                if self.peek() != Some(b')') {
                    return self.error("expected ')'");
                }
                self.pos += 1;
                Ok(inner)
            }
            Some(c) if c.is_ascii_digit() || c == b'.' => self.number(),
            Some(c) if c.is_ascii_alphabetic() => {
                let start = self.pos;
                while self.pos < self.text.len() && self.text[self.pos].is_ascii_alphanumeric() {
                    self.pos += 1;
                }
                let name = String::from_utf8_lossy(&self.text[start..self.pos]).into_owned();
                match name.as_str() {
                    "t" => Ok(Node::T),
                    "pi" => Ok(Node::Num(std::f64::consts::PI)),
                    "e" => Ok(Node::Num(std::f64::consts::E)),
                    _ => {
                        let Some(f) = Func::from_name(&name) else {
                            self.pos = start;
                            return self.error(format!(
                                "unknown name {name:?} (use t, pi, e, sin, cos, tan, exp, ln, \
                                 sqrt, abs, sinh, cosh, tanh)"
                            ));
                        };
                        if self.peek() != Some(b'(') {
                            return self.error(format!("expected '(' after {name}"));
                        }
                        self.pos += 1;
                        let arg = self.sum()?;
                        if self.peek() != Some(b')') {
                            return self.error("expected ')'");
                        }
                        self.pos += 1;
                        Ok(Node::Call(f, Box::new(arg)))
                    }
                }
            }
            Some(_) => {
                // The character, not its first byte: the parser moves over ASCII only, so the
                // rest of the text starts at a character's boundary.
                let c = std::str::from_utf8(&self.text[self.pos..])
                    .ok()
                    .and_then(|rest| rest.chars().next())
                    .unwrap_or(char::REPLACEMENT_CHARACTER);
                self.error(format!("unexpected {c:?}"))
            }
            None => self.error("unexpected end of expression"),
        }
    }

    fn number(&mut self) -> Result<Node, ExprError> {
        let start = self.pos;
        let t = self.text;
        while self.pos < t.len() && (t[self.pos].is_ascii_digit() || t[self.pos] == b'.') {
            self.pos += 1;
        }
        if self.pos < t.len() && (t[self.pos] == b'e' || t[self.pos] == b'E') {
            let save = self.pos;
            self.pos += 1;
            if self.pos < t.len() && (t[self.pos] == b'+' || t[self.pos] == b'-') {
                self.pos += 1;
            }
            if self.pos < t.len() && t[self.pos].is_ascii_digit() {
                while self.pos < t.len() && t[self.pos].is_ascii_digit() {
                    self.pos += 1;
                }
            } else {
                self.pos = save;
            }
        }
        let s = String::from_utf8_lossy(&t[start..self.pos]);
        match s.parse::<f64>() {
            Ok(v) => Ok(Node::Num(v)),
            Err(_) => {
                self.pos = start;
                self.error(format!("bad number {s:?}"))
            }
        }
    }
}

impl Expr {
    /// Parses an expression in `t`.
    pub fn parse(text: &str) -> Result<Self, ExprError> {
        if text.len() > MAX_LEN {
            return Err(ExprError {
                position: MAX_LEN,
                message: format!("longer than {MAX_LEN} characters"),
            });
        }
        let mut p = Parser {
            text: text.as_bytes(),
            pos: 0,
            depth: 0,
        };
        let node = p.sum()?;
        if p.peek().is_some() {
            return p.error("unexpected text after the expression");
        }
        Ok(Expr(node))
    }

    /// The value at `t` (may be non-finite: callers check).
    pub fn eval(&self, t: f64) -> f64 {
        fn go(n: &Node, t: f64) -> f64 {
            match n {
                Node::Num(v) => *v,
                Node::T => t,
                Node::Neg(a) => -go(a, t),
                Node::Bin(op, a, b) => {
                    let (a, b) = (go(a, t), go(b, t));
                    match op {
                        '+' => a + b,
                        '-' => a - b,
                        '*' => a * b,
                        '/' => a / b,
                        _ => a.powf(b),
                    }
                }
                Node::Call(f, a) => f.apply(go(a, t)),
            }
        }
        go(&self.0, t)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn evaluates_with_precedence() {
        let e = Expr::parse("1 + 2 * t ^ 2 - -3 / (1 + 1)").unwrap();
        assert_eq!(e.eval(2.0), 1.0 + 8.0 + 1.5);
        let e = Expr::parse("-t^2").unwrap();
        assert_eq!(e.eval(3.0), -9.0);
        let e = Expr::parse("2^3^2").unwrap();
        assert_eq!(e.eval(0.0), 512.0);
        let e = Expr::parse("0.3*sin(2*pi*t) + 1.5e-1*cos(t)").unwrap();
        assert!((e.eval(0.25) - (0.3 + 0.15 * 0.25f64.cos())).abs() < 1e-15);
        assert!((Expr::parse("ln(e)").unwrap().eval(0.0) - 1.0).abs() < 1e-15);
    }

    /// A scenario file is input: however deep or long its expression, the answer is a parse
    /// error, never a parser, evaluator or destructor recursing off the end of the stack.
    #[test]
    fn deep_or_long_expressions_are_refused() {
        let k = 100_000;
        let parens = format!("{}t{}", "(".repeat(k), ")".repeat(k));
        let signs = format!("{}t", "-".repeat(k));
        let calls = format!("{}t{}", "sin(".repeat(k), ")".repeat(k));
        let powers = vec!["t"; k].join("^");
        let sum = vec!["t"; k].join("+");
        // Within the length, too deep.
        let k = 1000;
        let short_parens = format!("{}t{}", "(".repeat(k), ")".repeat(k));
        let short_signs = format!("{}t", "-".repeat(k));
        let short_powers = vec!["t"; k].join("^");
        for text in [
            &parens,
            &signs,
            &calls,
            &powers,
            &sum,
            &short_parens,
            &short_signs,
            &short_powers,
        ] {
            let e = Expr::parse(text).unwrap_err();
            assert!(e.message.len() < 100, "{e}");
        }
        // Nesting and length that any curve needs still parse.
        let nested = format!("{}t{}", "(".repeat(60), ")".repeat(60));
        assert_eq!(Expr::parse(&nested).unwrap().eval(2.0), 2.0);
        let long = vec!["t"; 1000].join("+");
        assert_eq!(Expr::parse(&long).unwrap().eval(1.0), 1000.0);
    }

    #[test]
    fn errors_point_at_the_problem() {
        assert_eq!(Expr::parse("t +").unwrap_err().position, 3);
        assert_eq!(Expr::parse("foo(t)").unwrap_err().position, 0);
        assert_eq!(Expr::parse("sin t").unwrap_err().position, 4);
        assert_eq!(Expr::parse("(t").unwrap_err().position, 2);
        assert_eq!(Expr::parse("t t").unwrap_err().position, 2);
        assert!(Expr::parse("").is_err());
    }
}
