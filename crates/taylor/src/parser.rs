//! A parser for Flow*'s expression syntax: `(1 - x^2)*y - x`, `sin(theta)`, `[0.1, 0.2]*u`,
//! `min`, `max`, `clip` and `where(lhs cmp rhs, then, otherwise)` (so [`Expr`]'s printed form
//! reads back), and the comparisons of guards and invariants (`x <= 0.5`). Precedence, loosest
//! first: `+ -`, `* /`, unary minus, `^` with a signed number (no chains), so `-x^2` is `-(x^2)`
//! as in Flow*. Python's `percver.formats.flowstar_syntax` reads model files with this grammar;
//! its tests check the two agree on random expressions.
use crate::error::{Result, TaylorError};
use crate::expr::{BinOp, Cmp, Expr};
use crate::functions::Func;
use crate::interval::Interval;

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Num(f64),
    Ident(String),
    Sym(char),
    Cmp(Cmp),
}

struct Parser<'a> {
    src: &'a str,
    tokens: Vec<(Token, usize)>,
    pos: usize,
}

fn lex(src: &str) -> Result<Vec<(Token, usize)>> {
    let bytes = src.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i] as char;
        if c.is_whitespace() {
            i += 1;
        } else if c.is_ascii_digit() || (c == '.' && i + 1 < bytes.len() && (bytes[i + 1] as char).is_ascii_digit()) {
            // digits ['.' digits] or '.' digits: a second '.' starts the next token
            let start = i;
            let digits = |mut i: usize| {
                while i < bytes.len() && (bytes[i] as char).is_ascii_digit() {
                    i += 1;
                }
                i
            };
            i = digits(i);
            if i < bytes.len() && bytes[i] == b'.' {
                i = digits(i + 1);
            }
            if i < bytes.len() && (bytes[i] == b'e' || bytes[i] == b'E') {
                let mut j = i + 1;
                if j < bytes.len() && (bytes[j] == b'+' || bytes[j] == b'-') {
                    j += 1;
                }
                if j < bytes.len() && (bytes[j] as char).is_ascii_digit() {
                    i = j;
                    while i < bytes.len() && (bytes[i] as char).is_ascii_digit() {
                        i += 1;
                    }
                }
            }
            let text = &src[start..i];
            let v: f64 = text.parse().map_err(|_| err(src, start, &format!("bad number '{text}'")))?;
            if !v.is_finite() {
                return Err(err(src, start, &format!("number '{text}' overflows to infinity; expressions take finite numbers only")));
            }
            out.push((Token::Num(v), start));
        } else if c.is_ascii_alphabetic() || c == '_' {
            let start = i;
            while i < bytes.len() && ((bytes[i] as char).is_ascii_alphanumeric() || bytes[i] == b'_') {
                i += 1;
            }
            out.push((Token::Ident(src[start..i].to_string()), start));
        } else if c == '<' || c == '>' || c == '=' {
            let start = i;
            let eq = i + 1 < bytes.len() && bytes[i + 1] == b'=';
            let cmp = match (c, eq) {
                ('<', true) => Cmp::Le,
                ('<', false) => Cmp::Lt,
                ('>', true) => Cmp::Ge,
                ('>', false) => Cmp::Gt,
                _ => return Err(err(src, start, "'=' is not an expression operator (use <= or >=)")),
            };
            i += if eq { 2 } else { 1 };
            out.push((Token::Cmp(cmp), start));
        } else if "+-*/^(),[]".contains(c) {
            out.push((Token::Sym(c), i));
            i += 1;
        } else {
            return Err(err(src, i, &format!("unexpected character '{c}'")));
        }
    }
    Ok(out)
}

fn err(src: &str, column: usize, message: &str) -> TaylorError {
    TaylorError::Parse { message: message.to_string(), column: column + 1, source_text: src.to_string() }
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.pos).map(|t| &t.0)
    }
    fn column(&self) -> usize {
        self.tokens.get(self.pos).map_or(self.src.len(), |t| t.1)
    }
    fn fail<T>(&self, message: &str) -> Result<T> {
        Err(err(self.src, self.column(), message))
    }
    fn expect(&mut self, c: char) -> Result<()> {
        if self.peek() == Some(&Token::Sym(c)) {
            self.pos += 1;
            Ok(())
        } else {
            self.fail(&format!("expected '{c}'"))
        }
    }

    fn sum(&mut self) -> Result<Expr> {
        let mut lhs = self.product()?;
        while let Some(Token::Sym(c @ ('+' | '-'))) = self.peek().cloned() {
            self.pos += 1;
            let rhs = self.product()?;
            lhs = Expr::binary(if c == '+' { BinOp::Add } else { BinOp::Sub }, &lhs, &rhs);
        }
        Ok(lhs)
    }

    fn product(&mut self) -> Result<Expr> {
        let mut lhs = self.unary()?;
        while let Some(Token::Sym(c @ ('*' | '/'))) = self.peek().cloned() {
            self.pos += 1;
            let rhs = self.unary()?;
            lhs = Expr::binary(if c == '*' { BinOp::Mul } else { BinOp::Div }, &lhs, &rhs);
        }
        Ok(lhs)
    }

    fn unary(&mut self) -> Result<Expr> {
        match self.peek() {
            Some(Token::Sym('-')) => {
                self.pos += 1;
                Ok(self.unary()?.neg())
            }
            Some(Token::Sym('+')) => {
                self.pos += 1;
                self.unary()
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Expr> {
        let base = self.atom()?;
        if self.peek() == Some(&Token::Sym('^')) {
            self.pos += 1;
            let exponent = self.signed_number("after '^' (exponents must be constants)")?;
            // Right-associative: x^2^3 = x^(2^3) is rare; reject to avoid surprises.
            if self.peek() == Some(&Token::Sym('^')) {
                return self.fail("chained '^' is ambiguous; add parentheses");
            }
            return Ok(base.powf(exponent));
        }
        Ok(base)
    }

    fn atom(&mut self) -> Result<Expr> {
        match self.peek().cloned() {
            Some(Token::Num(v)) => {
                self.pos += 1;
                Ok(Expr::constant(v))
            }
            Some(Token::Sym('(')) => {
                self.pos += 1;
                let e = self.sum()?;
                self.expect(')')?;
                Ok(e)
            }
            Some(Token::Sym('[')) => {
                self.pos += 1;
                let lo = self.signed_number("for an interval bound")?;
                self.expect(',')?;
                let hi = self.signed_number("for an interval bound")?;
                self.expect(']')?;
                let iv = Interval::new(lo, hi).map_err(|e| err(self.src, self.column(), &e.to_string()))?;
                Ok(Expr::uncertain(iv, false))
            }
            Some(Token::Ident(name)) => {
                self.pos += 1;
                if self.peek() == Some(&Token::Sym('(')) {
                    self.pos += 1;
                    if name == "where" {
                        return self.select();
                    }
                    let mut args = vec![self.sum()?];
                    while self.peek() == Some(&Token::Sym(',')) {
                        self.pos += 1;
                        args.push(self.sum()?);
                    }
                    self.expect(')')?;
                    return self.call(&name, args);
                }
                Ok(Expr::var(&name))
            }
            _ => self.fail("expected a number, variable, function call, '(' or '['"),
        }
    }

    /// `lhs cmp rhs`; `what` ends the message when there is no comparison.
    fn comparison(&mut self, what: &str) -> Result<(Expr, Cmp, Expr)> {
        let lhs = self.sum()?;
        let cmp = match self.peek() {
            Some(Token::Cmp(c)) => *c,
            _ => return self.fail(&format!("expected a comparison (<, <=, >, >=){what}")),
        };
        self.pos += 1;
        Ok((lhs, cmp, self.sum()?))
    }

    /// A number with an optional sign; `what` ends the message when there is none.
    fn signed_number(&mut self, what: &str) -> Result<f64> {
        let negative = match self.peek() {
            Some(Token::Sym(c @ ('-' | '+'))) => {
                let negative = *c == '-';
                self.pos += 1;
                negative
            }
            _ => false,
        };
        match self.peek().cloned() {
            Some(Token::Num(v)) => {
                self.pos += 1;
                Ok(if negative { -v } else { v })
            }
            _ => self.fail(&format!("expected a number {what}")),
        }
    }

    /// `where(lhs cmp rhs, then, otherwise)` after its '(' (the printed form of [`Expr::select`]).
    fn select(&mut self) -> Result<Expr> {
        let (lhs, cmp, rhs) = self.comparison(" in where(lhs cmp rhs, then, otherwise)")?;
        self.expect(',')?;
        let then = self.sum()?;
        self.expect(',')?;
        let otherwise = self.sum()?;
        self.expect(')')?;
        Ok(Expr::select(&lhs, cmp, &rhs, &then, &otherwise))
    }

    fn call(&self, name: &str, args: Vec<Expr>) -> Result<Expr> {
        let arity = |n: usize| -> Result<()> {
            if args.len() == n {
                Ok(())
            } else {
                self.fail(&format!("{name} takes {n} argument(s), got {}", args.len()))
            }
        };
        match name {
            "min" | "max" => {
                arity(2)?;
                Ok(Expr::binary(if name == "min" { BinOp::Min } else { BinOp::Max }, &args[0], &args[1]))
            }
            "clip" => {
                arity(3)?;
                Ok(args[0].clip(&args[1], &args[2]))
            }
            _ => match Func::from_name(name) {
                Some(f) => {
                    arity(1)?;
                    Ok(Expr::func(f, &args[0]))
                }
                None => self
                    .fail(&format!("unknown function '{name}' (known: exp log sqrt sin cos tan atan tanh sigmoid abs min max clip where)")),
            },
        }
    }
}

/// Parses one expression.
pub fn parse_expr(src: &str) -> Result<Expr> {
    let mut p = Parser { src, tokens: lex(src)?, pos: 0 };
    if p.tokens.is_empty() {
        return Err(err(src, 0, "empty expression"));
    }
    let e = p.sum()?;
    if p.pos != p.tokens.len() {
        return p.fail("unexpected text after the expression");
    }
    Ok(e)
}

/// Parses a constraint `lhs <= rhs` (or <, >=, >) into (lhs, cmp, rhs).
pub fn parse_constraint(src: &str) -> Result<(Expr, Cmp, Expr)> {
    let mut p = Parser { src, tokens: lex(src)?, pos: 0 };
    let (lhs, cmp, rhs) = p.comparison("")?;
    if p.pos != p.tokens.len() {
        return p.fail("unexpected text after the constraint");
    }
    Ok((lhs, cmp, rhs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::{FloatBatch, Program};

    fn eval(src: &str, x: f64, y: f64) -> f64 {
        let e = parse_expr(src).unwrap();
        let p = Program::compile(&[e], &["x".into(), "y".into()]).unwrap();
        p.eval(&FloatBatch::new(1), &[vec![x], vec![y]]).unwrap()[0][0]
    }

    #[test]
    fn precedence_matches_flowstar() {
        assert_eq!(eval("(1 - x^2)*y - x", 2.0, 3.0), (1.0 - 4.0) * 3.0 - 2.0);
        assert_eq!(eval("-x^2", 3.0, 0.0), -9.0);
        assert_eq!(eval("x - y - 1", 5.0, 1.0), 3.0);
        assert_eq!(eval("x / y / 2", 8.0, 2.0), 2.0);
        assert_eq!(eval("2e-1*x + .5", 1.0, 0.0), 0.7);
        assert!((eval("sin(x)^2 + cos(x)^2", 0.7, 0.0) - 1.0).abs() < 1e-15);
        assert_eq!(eval("x^-1", 4.0, 0.0), 0.25);
        assert_eq!(eval("clip(x, -1, 1)", 4.0, 0.0), 1.0);
        assert_eq!(eval("where(x >= y, x, y) + x^+2", 2.0, 3.0), 7.0);
        assert_eq!(eval("[+1, 1] * x", 2.0, 0.0), 2.0);
    }

    #[test]
    fn printed_expressions_read_back() {
        for src in ["where(x >= 0.5, min(x, -1.5e-7), max(y, 2.0))", "((x^-2) * [-1.0, 2.0])", "(-(x + (y^0.5)))"] {
            let e = parse_expr(src).unwrap();
            assert_eq!(parse_expr(&e.to_string()).unwrap().to_string(), e.to_string());
        }
        // a second '.' starts a new token, which cannot follow a number
        assert!(parse_expr("1.2.3").unwrap_err().to_string().contains("unexpected text"));
    }

    #[test]
    fn errors_point_at_the_problem() {
        let e = parse_expr("x + * y").unwrap_err().to_string();
        assert!(e.contains("column 5"), "{e}");
        assert!(parse_expr("foo(x)").unwrap_err().to_string().contains("unknown function"));
        assert!(parse_expr("x $ y").is_err());
        assert!(parse_expr("").is_err());
        assert!(parse_expr("(x + y").is_err());
        // an overflowing literal would be an infinite constant: bounds and evaluation disagree
        let e = parse_expr("x * 1e999").unwrap_err().to_string();
        assert!(e.contains("'1e999' overflows to infinity") && e.contains("column 5"), "{e}");
    }

    #[test]
    fn interval_constants_and_constraints() {
        let e = parse_expr("[0.1, 0.2] * x").unwrap();
        assert!(e.to_string().contains("0.1"));
        let (l, c, r) = parse_constraint("x + y <= 0.5").unwrap();
        assert_eq!(c, Cmp::Le);
        assert_eq!(l.variables(), vec!["x", "y"]);
        assert!(r.variables().is_empty());
    }
}
